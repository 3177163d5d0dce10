"""The coil's current source over SCPI: currents per axis, read back, output on and off.

Every setting is followed by the controller's error queue and a read-back of the driven current,
so a controller that refuses a value, trips its output or never switched it on errors the unit
with the instrument's own words instead of producing a calibration against a field that was
never there.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from magline.core.scpi import InstrumentError, ScpiInstrument
from magline.plugins.helmholtz.options import HelmholtzOptions


class CoilDriver:
    def __init__(self, options: HelmholtzOptions) -> None:
        self.opts = options
        self.constants = np.asarray(options.constants_ut_per_a, float)
        self.inst = ScpiInstrument(options.resource, options.timeout_s)
        self.identity = self.inst.query("*IDN?")
        self.inst.errors()
        self.ambient_ut = np.zeros(3)  # estimated by nulling; cancelled in every applied vector
        self.on = False

    def currents_for(self, field_ut: NDArray) -> NDArray:
        """Currents that make ``field_ut`` at the centre, the ambient field cancelled."""
        currents = (np.asarray(field_ut, float) - self.ambient_ut) / self.constants
        too_big = np.abs(currents) > self.opts.max_current_a
        if too_big.any():
            axis = "xyz"[int(np.argmax(too_big))]
            raise InstrumentError(f"{self.inst.resource}: {field_ut} µT needs {currents.round(3).tolist()} A; "
                                  f"axis {axis} exceeds the station's max_current_a = {self.opts.max_current_a:g} A")
        return currents

    def apply(self, field_ut: NDArray) -> None:
        self.set_currents(self.currents_for(field_ut))

    def set_currents(self, currents: NDArray) -> None:
        for n, amps in enumerate(currents, start=1):
            self.inst.write(f"SOUR{n}:CURR {amps:.5f}")
        self.inst.check("setting the coil currents")
        if not self.on:
            self.inst.write("OUTP ON")
            self.inst.check("coil output on")
            self.on = True
        for n, amps in enumerate(currents, start=1):
            measured = self.inst.query_float(f"MEAS{n}:CURR?")
            if abs(measured - amps) > self.opts.current_tolerance_a:
                self.inst.check(f"channel {n} read-back")  # the controller's own reason first
                raise InstrumentError(f"{self.inst.resource}: coil channel {n} set to {amps:.4f} A but drives "
                                      f"{measured:.4f} A (output off or tripped?)")

    def off(self) -> None:
        """Zero the currents and switch the output off (the end of every unit, also after errors)."""
        try:
            for n in (1, 2, 3):
                self.inst.write(f"SOUR{n}:CURR 0")
            self.inst.write("OUTP OFF")
            if self.inst.query("OUTP?") not in ("0", "OFF"):  # the query also waits for the writes
                raise InstrumentError(f"{self.inst.resource}: the coil output did not switch off")
        finally:
            self.on = False

    def close(self) -> None:
        self.inst.close()
