"""The coil's current source over SCPI: currents per axis, read back, output on and off.

Every setting is followed by the controller's error queue and a read-back of the driven current,
so a controller that refuses a value, trips its output or never switched it on errors the unit
with the instrument's own words instead of producing a calibration against a field that was
never there.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from magline.plugin import InstrumentError, ScpiInstrument

if TYPE_CHECKING:
    from magline.plugins.helmholtz.options import HelmholtzOptions


class Channel:
    """One axis: an instrument and the commands that set, read back and switch its current."""

    def __init__(self, inst: ScpiInstrument, set_cmd: str, meas_cmd: str, shared: bool) -> None:
        self.inst, self.set_cmd, self.meas_cmd, self.shared = inst, set_cmd, meas_cmd, shared


class CoilDriver:
    def __init__(self, options: HelmholtzOptions) -> None:
        self.opts = options
        self.constants = np.asarray(options.constants_ut_per_a, float)
        if options.resource is not None:  # one three-channel controller: SOURn:CURR / MEASn:CURR?
            inst = ScpiInstrument(options.resource, options.timeout_s)
            self.instruments = [inst]
            self.channels = [Channel(inst, f"SOUR{n}:CURR", f"MEAS{n}:CURR?", True) for n in (1, 2, 3)]
        else:  # three bipolar single-channel sources: CURR / MEAS:CURR?
            self.instruments = [ScpiInstrument(r, options.timeout_s) for r in options.resources or []]
            self.channels = [Channel(inst, "CURR", "MEAS:CURR?", False) for inst in self.instruments]
        for inst in self.instruments:
            inst.query("*IDN?")
            inst.errors()
        self.ambient_ut = np.zeros(3)  # estimated by nulling; cancelled in every applied vector
        self.on = False

    def currents_for(self, field_ut: NDArray) -> NDArray:
        """Currents that make ``field_ut`` at the centre, the ambient field cancelled."""
        currents = (np.asarray(field_ut, float) - self.ambient_ut) / self.constants
        too_big = np.abs(currents) > self.opts.max_current_a
        if too_big.any():
            axis = "xyz"[int(np.argmax(too_big))]
            raise InstrumentError(f"coil: {field_ut} µT needs {currents.round(3).tolist()} A; "
                                  f"axis {axis} exceeds the station's max_current_a = {self.opts.max_current_a:g} A")
        return currents

    def apply(self, field_ut: NDArray) -> None:
        self.set_currents(self.currents_for(field_ut))

    def set_currents(self, currents: NDArray) -> None:
        for channel, amps in zip(self.channels, currents, strict=True):
            channel.inst.write(f"{channel.set_cmd} {amps:.5f}")
        for inst in self.instruments:
            inst.check("setting the coil currents")
        if not self.on:
            for inst in self.instruments:
                inst.write("OUTP ON")
                inst.check("coil output on")
            self.on = True
        for n, (channel, amps) in enumerate(zip(self.channels, currents, strict=True), start=1):
            measured = channel.inst.query_float(channel.meas_cmd)
            if abs(measured - amps) > self.opts.current_tolerance_a:
                channel.inst.check(f"channel {n} read-back")  # the controller's own reason first
                raise InstrumentError(f"{channel.inst.resource}: coil channel {n} set to {amps:.4f} A but drives "
                                      f"{measured:.4f} A (output off or tripped?)")

    def off(self) -> None:
        """Zero the currents and switch the outputs off (the end of every unit, also after errors)."""
        try:
            for channel in self.channels:
                channel.inst.write(f"{channel.set_cmd} 0")
            for inst in self.instruments:
                inst.write("OUTP OFF")
                if inst.query("OUTP?") not in ("0", "OFF"):  # the query also waits for the writes
                    raise InstrumentError(f"{inst.resource}: the coil output did not switch off")
        finally:
            self.on = False

    def close(self) -> None:
        for inst in self.instruments:
            inst.close()
