"""``electronic-load``: the interference sweep's current drawn by a programmable DC electronic load over
SCPI, wired into the unit's power path downstream of its current sensor.

Why the preferred source: the current is set, not guessed, the same on every unit, with the propellers
nowhere near; and the load measures what it sinks, so the unit's own current sensor is checked
against it (a power module's wrong scale FAILs, ``current_sensor_error_pct``).  Safety: the input goes
on at 0 A and off at every end, also after errors; the set current never exceeds the product's
``current_max_a`` nor the load's ``max_current_a``; an error in the load's queue is an ERROR.
The commands are the common constant-current subset (``CURR``, ``INP``, ``MEAS:CURR?``); a load that
spells them otherwise names its own in ``commands``.  ``bench-supply`` is the same source for a line
whose programmable supply drives the current in constant-current mode through the unit's power path
into a fixed resistor: ``VOLT`` (its compliance voltage, ``volts``), ``CURR``, ``OUTP ON|OFF``,
``MEAS:CURR?`` — a supply that only powers the unit cannot set a current, and is not one.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

from pydantic import BaseModel, ConfigDict, Field

from magline.plugin import CurrentSourceError, InstrumentError, ScpiInstrument

if TYPE_CHECKING:
    from magline.plugin import CurrentSourceConfig, RunContext


class LoadCommands(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, defer_build=True)
    setup: list[str] = Field(default_factory=list)
    """SCPI commands sent once per unit before the input goes on (``{volts}`` is filled in)."""
    set_current: str = "CURR {amps:.3f}"
    """Sets the current drawn (``{amps}`` is filled in)."""
    input_on: str = "INP ON"
    """Switches the input on."""
    input_off: str = "INP OFF"
    """Switches the input off."""
    measure_current: str = "MEAS:CURR?"
    """Asks for the current measured."""


class SupplyCommands(LoadCommands):
    """A programmable bench supply in constant-current mode, driving the current through the unit's power
    path into a fixed resistor: its compliance voltage first, then its output."""

    setup: list[str] = Field(default_factory=lambda: ["VOLT {volts:.3f}"])
    """SCPI commands sent once per unit before the output goes on (``{volts}`` is filled in)."""
    input_on: str = "OUTP ON"
    """Switches the output on."""
    input_off: str = "OUTP OFF"
    """Switches the output off."""


class ElectronicLoadOptions(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, defer_build=True)
    resource: str
    """The instrument, e.g. TCPIP0::192.168.10.30::5025::SOCKET."""
    max_current_a: Annotated[float, Field(gt=0, le=1000)] = 60.0
    """The instrument's rating: it is never asked for more."""
    timeout_s: Annotated[float, Field(gt=0)] = 2.0
    """One SCPI reply."""
    volts: Annotated[float, Field(gt=0, le=100)] = 12.0
    """A supply's compliance voltage (``{volts}`` in ``commands.setup``)."""
    commands: LoadCommands = Field(default_factory=LoadCommands)
    """The instrument's SCPI commands (below)."""


class BenchSupplyOptions(ElectronicLoadOptions):
    commands: SupplyCommands = Field(default_factory=SupplyCommands)
    """The supply's SCPI commands (below)."""


class ElectronicLoad:
    name = "electronic-load"

    def __init__(self, options: ElectronicLoadOptions | BenchSupplyOptions) -> None:
        self.opts = options
        self.inst: ScpiInstrument | None = None
        self.top_a = 0.0

    def _connected(self) -> ScpiInstrument:
        if self.inst is None:
            try:
                self.inst = ScpiInstrument(self.opts.resource, self.opts.timeout_s)
                self.identity = self.inst.query("*IDN?")
                self.inst.errors()  # start from an empty queue: what was there belongs to someone else
            except InstrumentError as exc:
                raise CurrentSourceError(f"electronic load: {exc}") from exc
        return self.inst

    def _do(self, step: str, *commands: str) -> None:
        inst = self._connected()
        try:
            for command in commands:
                inst.write(command)
            inst.check(step)
        except InstrumentError as exc:
            raise CurrentSourceError(f"electronic load, {step}: {exc}") from exc

    def start(self, run: RunContext) -> None:
        top = float(run.product.current_max_a or 0.0)
        if top > self.opts.max_current_a:
            raise CurrentSourceError(f"the product's current_max_a {top:g} A is beyond the load's rating "
                                     f"({self.opts.max_current_a:g} A, current_source.options.max_current_a)")
        self.top_a = top
        c = self.opts.commands
        self._do("setup", *(command.format(volts=self.opts.volts) for command in c.setup))
        self._do("input on at 0 A", c.set_current.format(amps=0.0), c.input_on)

    def set_level(self, fraction: float) -> None:
        amps = min(max(fraction, 0.0), 1.0) * self.top_a
        self._do(f"setting {amps:.2f} A", self.opts.commands.set_current.format(amps=amps))

    def measured_current_a(self) -> float | None:
        inst = self._connected()
        try:
            value = inst.query_float(self.opts.commands.measure_current)
            inst.check("current measurement")
        except InstrumentError as exc:
            raise CurrentSourceError(f"electronic load, current measurement: {exc}") from exc
        return value

    def stop(self) -> None:
        if self.inst is None:
            return
        c = self.opts.commands
        self._do("input off", c.set_current.format(amps=0.0), c.input_off)

    def close(self) -> None:
        if self.inst is not None:
            self.inst.close()
            self.inst = None


def create_electronic_load(config: CurrentSourceConfig, station_dir: Path,
                           options: ElectronicLoadOptions) -> ElectronicLoad:
    return ElectronicLoad(options)


def create_bench_supply(config: CurrentSourceConfig, station_dir: Path, options: BenchSupplyOptions) -> ElectronicLoad:
    """``bench-supply``: the same source spoken to as a programmable supply in constant-current mode."""
    source = ElectronicLoad(options)
    source.name = "bench-supply"
    return source
