"""From a sweep to each compass's field change per amp, with its σ, linearity and return to zero.

Per compass, every reading of every step is a row: its calibrated field ``S·(m − h)`` (the fit of
this run) against the step's current — a straight line ``a + c·I`` by least squares.  ``c`` (µT/A)
against the *reference* current (the load's own measurement, else the unit's) is the physical
figure judged; the same line of the *raw* readings against the unit's own current reading is what
the firmware compensates with, so it is what is written.  σ: the residual scatter of the readings
through the slope's leverage (``σ_res / √Σ(I − Ī)²`` per axis); the benchmark checks that it holds
the truth.  Linearity: the step means' largest distance from the line (a saturating core, a
current-dependent part).  Return to zero: the first and the last zero-current steps' difference.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from magline.core.faults import StationFault
from magline.core.interference.hold import known_pct, worth_writing
from magline.core.interference.line import length_sigma, line_fit

if TYPE_CHECKING:
    from magline.core.fit import FitResult
    from magline.core.interference.sweep import Sweep

# The unit's current reading must follow the reference: across the sweep its range at least this share
# of the reference's (a firmware that reads another battery monitor, or none, stays flat)
FOLLOWS_SHARE = 0.5
# The source reaching this share of the current asked at the top step counts as having reached it
REACHED_SHARE = 0.9
MOVED_DEG = 2.0  # the accelerometer turning more than this during the sweep: the unit moved


def zone_words(pct: float) -> str:
    """ArduPilot's bands in words (< 30 % fine, 30–60 % grey, > 60 % move the compass): what the operator,
    the screen and the report say of a compass's interference."""
    return "fine" if pct < 30.0 else "grey zone" if pct <= 60.0 else "move the compass"


@dataclass
class CompassInterference:
    device_id: int
    per_amp_ut: NDArray  # calibrated frame, µT per amp of the reference current
    per_amp_sigma_ut: float  # 1σ of its length
    per_amp_written_ut: NDArray  # the raw stream's frame, µT per amp of the unit's own reading: compensated
    written_sigma_ut: float  # 1σ per axis of the written slope
    linearity_ut: float
    return_ut: float
    pct_at_max: float
    step_fields_ut: list[list[float]] = field(default_factory=list)  # calibrated mean field per step

    @property
    def ut_per_a(self) -> float:
        return float(np.linalg.norm(self.per_amp_ut))

    @property
    def known_pct(self) -> float:
        """How well the written slope is known, 3σ as a share of itself (%): about what compensating
        with it may leave of this compass's interference."""
        return known_pct(float(np.linalg.norm(self.per_amp_written_ut)), self.written_sigma_ut)

    @property
    def worth_writing(self) -> bool:
        """Whether compensating with the written slope removes more than it adds, on average."""
        return worth_writing(float(np.linalg.norm(self.per_amp_written_ut)), self.written_sigma_ut)


@dataclass
class Interference:
    compasses: dict[int, CompassInterference]
    reference: str  # "source" (the load measured it) or "unit" (the unit's own reading)
    current_max_a: float
    field_ut: float
    sensor_error_pct: float | None  # the unit's reading against the source's (None: no measurement of its own)
    moved_deg: float
    seconds: float
    steps: list[dict] = field(default_factory=list)  # level, source and unit current per step (the record)
    readings_per_step: int = 0  # readings of every compass at each step (as the noise at 0 A asked)
    held_readings: int = 0  # read more at the top and the last zero for the compensation goal
    hold_asked: int = 0  # what the goal asked for there (more than held: the budget cut it)
    stream_hz: float = 0.0  # the rate the sweep's stream was asked for (0: not known)
    compensated: set[int] = field(default_factory=set)  # device ids whose compensation the persist phase writes

    def to_dict(self) -> dict:
        return {"reference": self.reference, "current_max_a": self.current_max_a, "field_ut": self.field_ut,
                "sensor_error_pct": self.sensor_error_pct, "moved_deg": self.moved_deg, "seconds": self.seconds,
                "steps": self.steps, "readings_per_step": self.readings_per_step,
                "held_readings": self.held_readings, "hold_asked": self.hold_asked, "stream_hz": self.stream_hz,
                "compasses": {str(d): {"per_amp_ut": c.per_amp_ut.tolist(), "per_amp_sigma_ut": c.per_amp_sigma_ut,
                                       "per_amp_written_ut": c.per_amp_written_ut.tolist(),
                                       "written_sigma_ut_per_a": c.written_sigma_ut,
                                       "known_pct": c.known_pct if np.isfinite(c.known_pct) else None,
                                       "linearity_ut": c.linearity_ut, "return_ut": c.return_ut,
                                       "pct_at_max": c.pct_at_max, "step_fields_ut": c.step_fields_ut}
                              for d, c in self.compasses.items()}}


def analyse(sweep: Sweep, fits: dict[int, FitResult], current_max_a: float, field_ut: float) -> Interference:
    """Each compass's interference from ``sweep``, its readings calibrated with ``fits`` (by device id).
    A sweep that cannot be judged — the source short of the top, the unit's reading not following, the
    unit moved — is a StationFault naming it."""
    steps = sweep.steps
    if any(not s.firmware_a for s in steps):
        raise StationFault("the unit reported no current during the sweep")
    unit_a = np.array([s.firmware_mean_a for s in steps], float)
    has_source = all(s.source_a is not None for s in steps)
    reference_a = np.array([s.source_a for s in steps], float) if has_source else unit_a
    top = float(np.max(reference_a))
    if has_source and top < REACHED_SHARE * current_max_a:
        raise StationFault(f"the current source reached only {top:.2f} A of the {current_max_a:g} A the sweep asks "
                           "for (its rating, its supply, or its leads)")
    span_ref = float(np.ptp(reference_a))
    if has_source and float(np.ptp(unit_a)) < FOLLOWS_SHARE * span_ref:
        raise StationFault(f"the unit's own current reading did not follow the source ({np.min(unit_a):.2f}–"
                           f"{np.max(unit_a):.2f} A while the source drew {np.min(reference_a):.2f}–{top:.2f} A): no "
                           "current sensor, or the source is not downstream of the battery monitor the firmware reads")
    moved = _moved_deg(steps)
    if moved > MOVED_DEG:
        raise StationFault(f"the unit moved during the current sweep: the accelerometer turned {moved:.1f}° (more than "
                           f"{MOVED_DEG:g}°): the field change would be the turn's, not the current's")
    sensor_error = None
    if has_source:
        _, gain, _ = line_fit(reference_a, unit_a[:, None])
        sensor_error = float((gain[0] - 1.0) * 100.0)
    compasses = {}
    for device_id in sweep.device_ids:
        fit = fits[device_id]
        raw_rows, cal_rows, ref_x, unit_x, means = [], [], [], [], []
        for step, ref, own in zip(steps, reference_a, unit_a, strict=True):
            raw = step.fields(device_id)
            cal = (raw - fit.hard_iron_ut) @ fit.soft_iron.T
            raw_rows.append(raw)
            cal_rows.append(cal)
            ref_x += [ref] * len(raw)
            unit_x += [own] * len(raw)
            means.append(cal.mean(axis=0))
        cal_all, raw_all = np.vstack(cal_rows), np.vstack(raw_rows)
        a, c, sigma = line_fit(np.array(ref_x), cal_all)
        _, written, written_sigma = line_fit(np.array(unit_x), raw_all)
        line = a + np.outer(reference_a, c)
        means_arr = np.array(means)
        compasses[device_id] = CompassInterference(
            device_id=device_id, per_amp_ut=c, per_amp_sigma_ut=length_sigma(c, sigma), per_amp_written_ut=written,
            written_sigma_ut=float(written_sigma[0]),
            linearity_ut=float(np.max(np.linalg.norm(means_arr - line, axis=1))),
            return_ut=float(np.linalg.norm(means_arr[-1] - means_arr[0])),
            pct_at_max=float(np.linalg.norm(c) * current_max_a / field_ut * 100.0),
            step_fields_ut=np.round(means_arr, 4).tolist())
    table = [{"level": s.level, "source_a": s.source_a, "unit_a": s.firmware_mean_a} for s in steps]
    return Interference(compasses=compasses, reference="source" if has_source else "unit", current_max_a=current_max_a,
                        field_ut=field_ut, sensor_error_pct=sensor_error, moved_deg=moved, seconds=sweep.seconds,
                        steps=table, readings_per_step=sweep.readings_per_step, held_readings=sweep.held_readings,
                        hold_asked=sweep.hold_asked, stream_hz=sweep.stream_hz)


def _moved_deg(steps) -> float:
    """The largest angle between the first step's gravity and any later step's (0 without readings)."""
    means = [np.mean(s.accel, axis=0) for s in steps if s.accel]
    if len(means) < 2:
        return 0.0
    first = means[0] / np.linalg.norm(means[0])
    return float(max(np.degrees(np.arccos(np.clip(m @ first / np.linalg.norm(m), -1.0, 1.0))) for m in means[1:]))
