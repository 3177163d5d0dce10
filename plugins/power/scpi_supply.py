"""``scpi-supply``: cut and restore the unit's power with a programmable bench supply over SCPI.

Safety order on every power-on: voltage and current limit are set (and the supply's error queue
checked) *before* the output goes on.  After power-on the current draw must sit inside the
station's window: a dead board (nothing connected, open fuse) draws too little, a shorted one
runs into the limit.  The supply's final state is set by the station file and is restored at the
end of every unit, also after errors.  An error in the supply's queue errors the unit.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from magline.plugin import DutError, InstrumentError, PowerError, ScpiInstrument, await_boot_after_cut

if TYPE_CHECKING:
    from magline.plugin import DutBackend, PowerConfig


class ScpiSupplyOptions(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, defer_build=True)
    resource: str
    """The bench supply, e.g. TCPIP0::192.168.10.21::5025::SOCKET or ASRL/dev/ttyUSB0::INSTR."""
    voltage_v: Annotated[float, Field(gt=0, le=60)] = 5.0
    """The unit's supply voltage."""
    current_limit_a: Annotated[float, Field(gt=0, le=10)] = 1.5
    """The supply's current limit."""
    off_time_s: Annotated[float, Field(ge=0)] = 2.0
    """How long the power stays off: long enough for the board's capacitors to drain."""
    settle_s: Annotated[float, Field(ge=0)] = 0.5
    """After power-on, before the unit's current is measured."""
    current_window_a: Annotated[list[float], Field(min_length=2, max_length=2)] = [0.05, 1.2]
    """[low, high]: the current a booting unit draws; outside it the power cycle fails."""
    final_state: Literal["on", "off"] = "on"
    """The supply's output when the station is done with the unit."""
    timeout_s: Annotated[float, Field(gt=0)] = 2.0
    """One SCPI reply."""

    @model_validator(mode="after")
    def _window(self) -> ScpiSupplyOptions:
        low, high = self.current_window_a
        if not 0 <= low < high <= self.current_limit_a:
            raise ValueError("current_window_a must be [low, high] with 0 <= low < high <= current_limit_a")
        return self


class ScpiSupply:
    method = "scpi-supply"

    def __init__(self, options: ScpiSupplyOptions) -> None:
        self.opts = options
        try:
            self.inst = ScpiInstrument(options.resource, options.timeout_s)
            self.identity = self.inst.query("*IDN?")
            self.inst.errors()  # start from an empty queue; what was there belongs to someone else
        except InstrumentError as exc:
            raise PowerError(str(exc)) from exc

    def _do(self, step: str, *commands: str) -> None:
        try:
            for command in commands:
                self.inst.write(command)
            self.inst.check(step)
        except InstrumentError as exc:
            raise PowerError(str(exc)) from exc

    def _measure_current(self) -> float:
        try:
            current = self.inst.query_float("MEAS:CURR?")
            self.inst.check("current measurement")
        except InstrumentError as exc:
            raise PowerError(str(exc)) from exc
        return current

    def _output_on(self) -> float:
        """Limits first, then output on; return the current after settling, checked against the window."""
        self._do("setting voltage and current limit", f"VOLT {self.opts.voltage_v:.3f}",
                 f"CURR {self.opts.current_limit_a:.3f}")
        self._do("output on", "OUTP ON")
        time.sleep(self.opts.settle_s)
        current = self._measure_current()
        low, high = self.opts.current_window_a
        if not low <= current <= high:
            what = "dead board or not connected" if current < low else "short circuit or overload"
            raise DutError(f"the unit draws {current:.3f} A after power-on, outside [{low:g}, {high:g}] A "
                           f"({what}) at {self.opts.voltage_v:g} V")
        return current

    def power_up(self) -> None:
        try:
            on = self.inst.query("OUTP?") in ("1", "ON")
        except InstrumentError as exc:
            raise PowerError(str(exc)) from exc
        if not on:
            self._output_on()

    def cycle(self, dut: DutBackend) -> dict[str, float | str]:
        dut.release_link()
        self._do("output off", "OUTP OFF")
        off_at = time.monotonic()
        time.sleep(self.opts.off_time_s)
        on_at = time.monotonic()
        current = self._output_on()
        figures = await_boot_after_cut(dut, on_at, "supply's cut")
        return {"method": self.method, "off_time_s": on_at - off_at, "current_after_power_on_a": current,
                **figures}

    def finish(self) -> None:
        if self.opts.final_state == "on":
            self._do("final state (on)", f"VOLT {self.opts.voltage_v:.3f}", f"CURR {self.opts.current_limit_a:.3f}",
                     "OUTP ON")
        else:
            self._do("final state (off)", "OUTP OFF")

    def close(self) -> None:
        self.inst.close()


def create_scpi_supply(config: PowerConfig, station_dir: Path, options: ScpiSupplyOptions) -> ScpiSupply:
    return ScpiSupply(options)
