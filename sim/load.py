"""A simulated programmable DC electronic load speaking SCPI over TCP, wired into a simulated flight
controller's power path downstream of its current sensor (issue 46).

The current it sinks flows through the board's current sensor (the board reports it, with that
sensor's own error, in BATTERY_STATUS) and through the power wiring next to its compasses (each sees
its own field per amp).  Switching its input on clamps the unit in its fixture: the simulated unit
keeps the attitude it has until the input goes off, as an operator sets the unit down for the sweep.

SCPI subset (as on common electronic loads, constant-current mode): ``*IDN?``, ``*RST``, ``*CLS``,
``CURR <a>``/``CURR?`` (the set current), ``INP ON|OFF``/``INP?``, ``MEAS:CURR?``, ``MEAS:VOLT?``,
``SYST:ERR?`` — and a supply's ``OUTP ON|OFF`` / ``VOLT <v>`` for the same, as a bench supply driving
the current in constant-current mode.  A current beyond the load's rating is refused with ``-222,"Data out of range"``.
Faults: ``no_sink`` (the input reports on but nothing flows: a lead not connected), ``rating_a=N``
(a smaller load than the line needs).
"""

from __future__ import annotations

from magline.sim.scpi_server import ScpiServer
from magline.sim.vehicle import SimulatedAutopilot

RATED_CURRENT_A = 60.0
FAULTS = ("no_sink",)


class LoadSim(ScpiServer):
    identity = "magline,SIM-ELOAD-600,0001,1.0"

    def __init__(self, listen: str = "tcp:127.0.0.1:5040", board: SimulatedAutopilot | None = None,
                 fault: str | None = None, rating_a: float = RATED_CURRENT_A) -> None:
        if fault is not None and fault not in FAULTS:
            raise ValueError(f"unknown load fault {fault!r}; choose from {', '.join(FAULTS)}")
        super().__init__(listen)
        self.board = board
        self.fault = fault
        self.rating_a = rating_a
        self.setpoint_a = 0.0
        self.input_on = False
        self.volts = 0.0
        if board is not None:
            board.current_provider = self.sinking_current

    def sinking_current(self) -> float:
        """The current flowing through the load (and the board's power path) now."""
        if not self.input_on or self.fault == "no_sink":
            return 0.0
        return self.setpoint_a

    def command(self, head: str, arg: str) -> str | None:
        head = head.removeprefix("SOUR:").removeprefix("SOURCE:").removeprefix(":")
        if head == "*RST":
            self._set_input(False)
            self.setpoint_a = 0.0
            return None
        if head in ("CURR?", "CURRENT?", "CURR:LEV?"):
            return f"{self.setpoint_a:.3f}"
        if head in ("INP?", "INPUT?", "INP:STAT?", "OUTP?", "OUTPUT?"):
            return "1" if self.input_on else "0"
        if head in ("MEAS:CURR?", "MEASURE:CURRENT?"):
            return f"{self.sinking_current():.4f}"
        if head in ("MEAS:VOLT?", "MEASURE:VOLTAGE?"):
            return "16.800" if self.board is not None else "0.000"
        if head in ("CURR", "CURRENT", "CURR:LEV"):
            try:
                value = float(arg)
            except ValueError:
                self.errors.append('-104,"Data type error"')
                return None
            if not 0.0 <= value <= self.rating_a:
                self.errors.append('-222,"Data out of range"')
                return None
            self.setpoint_a = value
            return None
        if head in ("VOLT", "VOLTAGE"):  # a supply in constant-current mode: its compliance voltage
            self.volts = float(arg)
            return None
        if head in ("INP", "INPUT", "INP:STAT", "OUTP", "OUTPUT"):
            state = arg.strip().upper()
            if state not in ("ON", "OFF", "1", "0"):
                self.errors.append('-224,"Illegal parameter value"')
                return None
            self._set_input(state in ("ON", "1"))
            return None
        return super().command(head, arg)

    def _set_input(self, on: bool) -> None:
        self.input_on = on
        if self.board is not None:
            self.board.hold_still(on)
