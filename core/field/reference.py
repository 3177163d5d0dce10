"""A reference magnetometer (three-axis fluxgate) read through a DMM / DAQ over SCPI, and the
batch checks built on it.

Why: a model (WMM) says what the field *should* be; steel racks, a forklift or a new bench supply
change what it *is*.  The reference is read at the start of a batch and every N units.  The
station refuses to calibrate when it disagrees with the model by more than the station's
tolerance, or when it drifts during the shift — with the figures in the message.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from magline.core.field import FieldSourceError
from magline.core.links.scpi import InstrumentError, ScpiInstrument
from magline.core.record import now_iso

if TYPE_CHECKING:
    import numpy as np

    from magline.core.field.options import ReferenceOptions


class Fluxgate:
    def __init__(self, options: ReferenceOptions) -> None:
        self.opts = options
        try:
            self.inst = ScpiInstrument(options.resource, options.timeout_s)
            self.identity = self.inst.query("*IDN?")
        except InstrumentError as exc:
            raise FieldSourceError(f"reference magnetometer: {exc}") from exc

    def read_ut(self) -> np.ndarray:
        """Field vector (µT), the average of ``readings`` DAQ scans."""
        import numpy as np  # here: the options model above is loaded by every command that reads a station

        scans = []
        try:
            for _ in range(self.opts.readings):
                answer = self.inst.query(f"MEAS:VOLT:DC? {self.opts.channels}")
                volts = [float(v) for v in answer.split(",")]
                if len(volts) != 3:
                    raise InstrumentError(f"{self.inst.resource}: expected 3 channels, got {answer!r}")
                scans.append(volts)
            self.inst.check("fluxgate reading")
        except (InstrumentError, ValueError) as exc:
            raise FieldSourceError(f"reference magnetometer: {exc}") from exc
        return np.mean(scans, axis=0) * self.opts.scale_ut_per_v

    def close(self) -> None:
        self.inst.close()


class ReferenceMonitor:
    """Checks the reference against the model at the batch start and every N units."""

    def __init__(self, options: ReferenceOptions, model_ut: float, model_name: str) -> None:
        self.opts = options
        self.model_ut = model_ut
        self.model_name = model_name
        self.fluxgate = Fluxgate(options)
        self.units = 0
        self.first_ut: float | None = None
        self.last: dict | None = None  # the latest fluxgate check (shown on the station screen)

    def before_unit(self) -> None:
        if self.units % self.opts.every_n_units == 0:
            self.check()
        self.units += 1

    def check(self) -> float:
        import numpy as np

        measured = float(np.linalg.norm(self.fluxgate.read_ut()))
        if abs(measured - self.model_ut) > self.opts.tolerance_ut:
            raise FieldSourceError(
                f"reference magnetometer reads {measured:.2f} µT, the {self.model_name} expects "
                f"{self.model_ut:.2f} µT (difference {measured - self.model_ut:+.2f} µT, "
                f"tolerance ±{self.opts.tolerance_ut:g} µT): the cell's field is disturbed — "
                "find the magnetic object or move the fixture before calibrating")
        self.last = {"measured_ut": round(measured, 3), "at": now_iso(), "after_units": self.units}
        if self.first_ut is None:
            self.first_ut = measured
        elif abs(measured - self.first_ut) > self.opts.drift_limit_ut:
            raise FieldSourceError(
                f"reference magnetometer drifted from {self.first_ut:.2f} µT at the batch start to {measured:.2f} µT "
                f"after {self.units} units (limit ±{self.opts.drift_limit_ut:g} µT): stop and find what changed")
        return measured

    def close(self) -> None:
        self.fluxgate.close()
