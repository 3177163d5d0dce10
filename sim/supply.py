"""A simulated programmable bench supply speaking SCPI over TCP, wired to a simulated flight controller.

Switching its output off really powers the board down (link silent, RAM lost, an unfinished save
lost — :meth:`SimulatedAutopilot.power_off`) and switching it on boots the board again, so the
power-cycle check of a station can be proven against the same traps a real fixture has.

SCPI subset (as on common bench supplies): ``*IDN?``, ``*RST``, ``*CLS``, ``VOLT <v>``/``VOLT?``,
``CURR <a>``/``CURR?`` (current limit), ``OUTP ON|OFF``/``OUTP?``, ``MEAS:VOLT?``, ``MEAS:CURR?``,
``SYST:ERR?``.  Errors go to the queue as instruments do (``-113,"Undefined header"``, ...).
Faults: ``dead_board`` (draws nothing, never boots), ``short`` (draws the limit, never boots),
``output_error`` (``OUTP ON`` is refused with an error in the queue).
"""

from __future__ import annotations

from magline.sim.scpi_server import ScpiServer
from magline.sim.vehicle import Power, SimulatedAutopilot

MAX_VOLTAGE, MAX_CURRENT = 30.0, 5.0
BOARD_MIN_VOLTAGE = 4.5
FAULTS = ("dead_board", "short", "output_error")


class SupplySim(ScpiServer):
    identity = "magline,SIM-PSU-3005,0001,1.0"

    def __init__(self, listen: str = "tcp:127.0.0.1:5025", board: SimulatedAutopilot | None = None,
                 idle_current_a: float = 0.25, boot_current_a: float = 0.35, fault: str | None = None) -> None:
        if fault is not None and fault not in FAULTS:
            raise ValueError(f"unknown supply fault {fault!r}; choose from {', '.join(FAULTS)}")
        super().__init__(listen)
        self.board = board
        self.idle_current_a = idle_current_a
        self.boot_current_a = boot_current_a
        self.fault = fault
        self.voltage = 0.0
        self.current_limit = 0.1
        self.output = False

    def command(self, head: str, arg: str) -> str | None:
        head = head.removeprefix("SOUR:").removeprefix("SOURCE:")
        if head == "*RST":
            self._set_output(False)
            self.voltage, self.current_limit = 0.0, 0.1
            return None
        if head in ("VOLT?", "VOLTAGE?"):
            return f"{self.voltage:.3f}"
        if head in ("CURR?", "CURRENT?"):
            return f"{self.current_limit:.3f}"
        if head in ("OUTP?", "OUTPUT?"):
            return "1" if self.output else "0"
        if head in ("MEAS:VOLT?", "MEASURE:VOLTAGE?"):
            return f"{self.voltage if self.output else 0.0:.3f}"
        if head in ("MEAS:CURR?", "MEASURE:CURRENT?"):
            return f"{self.measured_current():.4f}"
        if head in ("VOLT", "VOLTAGE", "CURR", "CURRENT"):
            self._set_level(head, arg)
            return None
        if head in ("OUTP", "OUTPUT"):
            state = arg.upper()
            if state not in ("ON", "OFF", "1", "0"):
                self.errors.append('-224,"Illegal parameter value"')
            elif state in ("ON", "1") and self.fault == "output_error":
                self.errors.append('-300,"Device-specific error; output protection tripped"')
            else:
                self._set_output(state in ("ON", "1"))
            return None
        raise KeyError(head)

    def _set_level(self, head: str, arg: str) -> None:
        try:
            value = float(arg)
        except ValueError:
            self.errors.append('-104,"Data type error"')
            return
        limit = MAX_VOLTAGE if head.startswith("VOLT") else MAX_CURRENT
        if not 0.0 <= value <= limit:
            self.errors.append('-222,"Data out of range"')
            return
        if head.startswith("VOLT"):
            self.voltage = value
        else:
            self.current_limit = value
        self._apply()

    def _set_output(self, on: bool) -> None:
        self.output = on
        self._apply()

    def _board_can_run(self) -> bool:
        return (self.output and self.fault not in ("dead_board", "short") and self.voltage >= BOARD_MIN_VOLTAGE
                and self.current_limit >= self.boot_current_a)

    def _apply(self) -> None:
        if self.board is None:
            return
        if self._board_can_run():
            self.board.power_on()
        elif self.board.power is not Power.OFF:
            self.board.power_off()

    def measured_current(self) -> float:
        if not self.output:
            return 0.0
        if self.fault == "dead_board":
            return 0.0
        if self.fault == "short" or not self._board_can_run():
            return self.current_limit if self.voltage > 0 else 0.0  # constant-current mode
        if self.board is None:
            return self.idle_current_a
        return self.boot_current_a if self.board.power is Power.BOOTING else self.idle_current_a
