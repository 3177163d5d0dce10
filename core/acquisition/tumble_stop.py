"""When a tumble is enough (``acquisition.stop: determined``): the running fit's rule built from the
station's limits, the mounting's σ targets, and the stall of a tumble that stopped covering new
directions.  The acquire phase (:mod:`magline.core.acquisition.tumble`) asks; the rule itself and the fit beside
the stream are :mod:`magline.core.fit.running`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from magline.core.fit.coverage import fibonacci_sphere
from magline.core.fit.running import PREDICTED, RunningFit, StopRule
from magline.core.measurements import limit_for
from magline.core.mounting.checks import calibrated, judge_mounting
from magline.core.mounting.estimate import MAX_SIGMA_DEG as MOUNTING_MAX_SIGMA_DEG
from magline.core.mounting.estimate import MountingUnobservable, estimate_mounting
from magline.core.mounting.line_skew import skew_prior

if TYPE_CHECKING:
    from magline.core.fit import FitResult
    from magline.core.fit.samples_csv import RawSamples
    from magline.core.mounting import ImuSeries
    from magline.core.sequencer.context import RunContext


class Stall:
    """When a determined tumble ends as *stalled* short of its coverage target, the operator asked again at
    once: reading on would not reach the target.

    Two ways to stall.  **Turned about the vertical only** (the classic mistake): the unit's gravity stays
    within :attr:`SPIN_CAP_DEG` of where it was from the tumble's start while the field's horizontal part has
    swept :attr:`SPIN_SWEEP_DEG` around it.  Turning about the vertical moves the field only around a cone
    about gravity, so no reading of that motion can reach a new ring; told from the accelerometer, it is
    known after half a turn.  Why not from the coverage: a ring's coverage creeps as its ill-determined
    centre moves, and each creep looked like a new direction (a spin was called at a median ~940 readings,
    some never).  A turntable's unit turns about the vertical by design: its guide asks for the tilts, and
    ``about_vertical=False`` leaves this rule out.

    **Nothing new any more**: no new direction of the field over the last two thirds of the readings (at
    least ``min_samples``), and — where the accelerometer is read — no new direction of gravity either, so
    a slow tumble whose field coverage pauses while gravity moves on is not called stalled.  Two thirds,
    not half: a turn there and back retraces as long as it went before it reaches new directions."""

    WITHOUT_GROWTH = 2 / 3  # the share of the readings with no new direction that is a stall
    SPIN_CAP_DEG = 30.0  # gravity within this of its mean since the start: the unit has not been tilted
    SPIN_SWEEP_DEG = 120.0  # the field's azimuth about gravity swept: the unit is being turned, not held
    LEAST_RING_UT = 5.0  # a ring of the field's horizontal part smaller than this is not read as turning

    def __init__(self, min_samples: int, target: float, *, about_vertical: bool = True,
                 field_ut: float | None = None, inclination_deg: float | None = None) -> None:
        self.min_samples, self.target, self.about_vertical = min_samples, target, about_vertical
        # the site's horizontal field, the radius of a ring turned about the vertical (None: not known)
        self.horizontal_ut = None if field_ut is None or inclination_deg is None else \
            field_ut * float(np.cos(np.radians(inclination_deg)))
        self.history: list[tuple[int, float]] = []  # (readings, coverage) at each change of coverage
        self.why = ""  # why the tumble stalled, in the log's words, once called
        self.about_vertical_only = False  # called for a turn about the vertical (else: nothing new any more)
        self._mags: list[np.ndarray] = []
        self._gravity: list[np.ndarray] = []  # one unit vector per chunk with accelerometer readings
        self._gravity_new_at = 0  # readings when gravity last showed a new direction
        self._gravity_cells: set[int] = set()  # the cells of GRAVITY_CELLS gravity has been in
        self._tilted = False  # gravity has left the spin cap since the start: no longer a spin about the vertical

    def see(self, mag_ut: np.ndarray, accel_mss: np.ndarray | None, count: int) -> None:
        """A chunk's raw readings and the accelerometer's readings over the same time (None: not read);
        ``count``: the readings so far as :meth:`stalled` is given them (a turntable counts its turns' only)."""
        mag = np.atleast_2d(np.asarray(mag_ut, float))
        if self.about_vertical and not self._tilted:
            self._mags.append(mag)
        if accel_mss is None or not len(accel_mss):
            return
        mean = np.mean(np.atleast_2d(accel_mss), axis=0)
        norm = float(np.linalg.norm(mean))
        if norm < 1e-6:
            return
        g = mean / norm
        cell = int(np.argmax(GRAVITY_CELLS @ g))
        if cell not in self._gravity_cells:
            self._gravity_cells.add(cell)
            self._gravity_new_at = count
        self._gravity.append(g)
        if not self._tilted and len(self._gravity) > 1:
            seen = np.array(self._gravity)
            centre = _unit(seen.sum(axis=0))
            self._tilted = float(np.degrees(np.arccos(np.clip(seen @ centre, -1.0, 1.0))).max()) > self.SPIN_CAP_DEG
            if self._tilted:
                self._mags = []

    def stalled(self, count: int, coverage: float) -> bool:
        if not self.history or coverage > self.history[-1][1]:
            self.history.append((count, coverage))
        if coverage >= self.target or count < 2 * self.min_samples:
            return False
        if self.about_vertical and not self._tilted and len(self._gravity) > 1 and self._turned_about_vertical():
            self.why, self.about_vertical_only = "turned about its vertical only", True
            return True
        since = self.history[-1][0]  # readings when the coverage last grew
        if self._gravity:
            since = max(since, self._gravity_new_at)
        if count - since >= max(self.min_samples, self.WITHOUT_GROWTH * count):
            self.why = "no new direction lately"
            return True
        return False

    def _turned_about_vertical(self) -> bool:
        """Has the field's part across gravity swept :attr:`SPIN_SWEEP_DEG`?  Read from the chord: the widest
        two readings of a ring of radius ``H`` (the site's horizontal field) that swept ``α`` lie ``2·H·sin(α/2)``
        apart, whatever the hard iron (it moves every reading alike) and however the hand wobbled the ring's
        plane (a circle fitted to a wobbled ring read its arc at twice its length)."""
        if self.horizontal_ut is None or self.horizontal_ut < self.LEAST_RING_UT:
            return False  # no site field known, or it is near vertical: a ring too small to read
        mag = np.vstack(self._mags)
        return _widest_ut(mag) >= 2.0 * self.horizontal_ut * np.sin(np.radians(self.SPIN_SWEEP_DEG) / 2.0)


def _widest_ut(points: np.ndarray) -> float:
    """The largest distance between two of ``points`` (through their convex spread: the extreme points along
    a few dozen directions, then every pair of those)."""
    directions = fibonacci_sphere(64)
    extreme = np.unique(np.concatenate([np.argmax(points @ directions.T, axis=0),
                                        np.argmin(points @ directions.T, axis=0)]))
    chosen = points[extreme]
    return float(np.max(np.linalg.norm(chosen[:, None, :] - chosen[None, :, :], axis=-1)))


# Gravity's directions in 40 near-equal cells (about 32° across, as the field's coverage bins): a new cell is
# a new attitude of the unit, the sign that a tumble is still going somewhere.
GRAVITY_CELLS = fibonacci_sphere(40)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def stop_rule(run: RunContext) -> StopRule:
    """When an acquisition has determined the calibration: each sensor's σ limits (and the fit's own
    heading refusal) with the station's margin, and its coverage limit where above the target.
    Shared by the tumble and the coil schedule (``plugins/helmholtz``)."""
    cfg = run.station.acquisition
    limits: dict[str, dict[str, float]] = {}
    coverage: dict[str, float] = {}
    for prefix in _sensors(run):
        if (floor := limit_for(prefix + "coverage", run.limits)) is not None and floor.low is not None:
            coverage[prefix] = floor.low  # the tumble that stops must also pass the coverage limit
        own = {name: limit.high for name in PREDICTED
               if (limit := limit_for(prefix + name, run.limits)) is not None and limit.high is not None}
        refusal = run.station.fit.max_direction_sigma_deg  # the fit refuses above it: never stop there
        own["direction_sigma_deg"] = min(own.get("direction_sigma_deg", refusal), refusal)
        limits[prefix] = own
    return StopRule(min_samples=cfg.min_samples, coverage_target=cfg.coverage_target,
                    margin=cfg.sigma_margin, limits=limits, coverage=coverage,
                    wait_for_drift_test=cfg.wait_for_drift_test)


def _sensors(run: RunContext) -> dict:
    return {run.sensor_prefix(m.device_id): m for m in run.magnetometers} or {"": None}


def running_fit(run: RunContext) -> RunningFit:
    """The fit beside the tumble: the station's own fit hook and settings for each sensor, judged
    by :func:`stop_rule`."""
    cfg = run.station.acquisition
    sensors = _sensors(run)
    rule = stop_rule(run)

    def fitter(prefix: str, samples: RawSamples) -> FitResult:
        return run.plugins.hook.magline_fit(run=run, samples=samples, options=run.fit_options(sensors[prefix]))

    confirm = None if run.product.orientation == "skip" else _mounting_determined(run, cfg.sigma_margin)
    return RunningFit(rule, fitter, confirm)


# How many σ of its estimate an error measurement must sit inside its limit, so that a good unit's
# noise alone crosses the limit in about 10⁻³ of units: a rotation's size (three axes, Maxwell tail)
# and a signed angle (one axis, two-sided normal).
ROTATION_Z, ONE_AXIS_Z = 4.0, 3.3
# How many σ an error's estimate must sit from each bound of its limit, inside or out, before the tumble
# may end.  Why: the σ targets above hold a good unit's noise inside the limit only where its error is
# near zero; a unit whose estimate happens to sit near the limit is decided by the coin of the next
# readings (a good PX4 unit read 2.79° ± 0.74° against 3°, another FAILed at 3.21°).  Such a unit reads
# on — to the acquisition's ``samples`` at most — until its estimate is clear of the limit either way: a
# good unit's error shrinks back towards zero, a bad one's stays out, and only units near the limit pay.
DECISION_Z = 2.0


def undecided(value: float, low: float | None, high: float | None, sigma: float) -> bool:
    """Whether ``value`` (with its 1σ) sits within :data:`DECISION_Z` σ of a bound: its verdict could
    still turn on the noise of the readings that follow."""
    return any(bound is not None and abs(value - bound) < DECISION_Z * sigma for bound in (low, high))


def _verdict_open(run: RunContext, name: str, value: float, sigma: float) -> bool:
    limit = limit_for(name, run.limits)
    return limit is not None and undecided(value, limit.low, limit.high, sigma)


def _limit_over(run: RunContext, name: str, z: float) -> float:
    """The σ an estimate may have so that noise alone stays inside the limit of ``name`` (∞: no limit)."""
    limit = limit_for(name, run.limits)
    if limit is None:
        return float("inf")
    bound = min(abs(v) for v in (limit.low, limit.high) if v is not None) if (
        limit.low is not None or limit.high is not None) else float("inf")
    return bound / z


def _mounting_sigma_target(run: RunContext, prefix: str, margin: float) -> float:
    """The mounting σ a determined tumble needs: inside the margin of what the check accepts (its
    ``mounting_sigma_deg`` limit, at most the estimator's bound) and small enough that a good unit's
    ``mounting_error_deg`` does not cross its limit by noise."""
    limit = limit_for(prefix + "mounting_sigma_deg", run.limits)
    bound = min(MOUNTING_MAX_SIGMA_DEG, limit.high if limit is not None and limit.high is not None
                else MOUNTING_MAX_SIGMA_DEG)
    return min(margin * bound, _limit_over(run, prefix + "mounting_error_deg", ROTATION_Z))


def _mounting_determined(run: RunContext, margin: float):
    """The mounting is proven from the same tumble (core/mounting): the tumble goes on until every
    sensor's mounting σ is within the margin of what the check needs (its ``mounting_sigma_deg``
    limit, at most the estimator's own bound), and its mounting and inclination errors are clear of
    their limits (:data:`DECISION_Z`).  A stream without an accelerometer never will be:
    then the stop does not wait, and the validate phase says the mounting cannot be proven."""
    skews: dict[str, float] = {}  # each sensor's skew found on an earlier snapshot: the next starts there
    sensors = _sensors(run)
    dip = getattr(run.field_source, "reference_inclination_deg", lambda: None)()  # as the validate phase reads it

    def confirm(fits: dict[str, FitResult], snapshot: dict[str, RawSamples], imu: ImuSeries | None):
        if imu is None or not len(imu) or not np.any(np.linalg.norm(imu.accel_mss, axis=1) > 1.0):
            return {}
        figures = {}
        for prefix, fit in fits.items():
            if fit.model == "affine":
                return {}
            samples = snapshot[prefix]
            try:
                estimate = estimate_mounting(calibrated(fit, samples.mag_ut, samples.t_ms), samples.t_ms, imu,
                                             skew_hint_ms=skews.get(prefix), dip_deg=dip,
                                             skew_prior=skew_prior(run, prefix))
            except MountingUnobservable:
                return None
            skews[prefix] = estimate.skew_ms
            if estimate.sigma_deg > _mounting_sigma_target(run, prefix, margin) or \
                    estimate.inclination_sigma_deg > _limit_over(run, prefix + "inclination_error_deg", ONE_AXIS_Z):
                return None
            figures[prefix] = {"mounting_sigma_deg": estimate.sigma_deg,
                               "inclination_sigma_deg": estimate.inclination_sigma_deg}
            sensor = sensors.get(prefix)
            if sensor is not None:
                error = figures[prefix]["mounting_error_deg"] = judge_mounting(sensor, estimate).error_deg
                if _verdict_open(run, prefix + "mounting_error_deg", error, estimate.sigma_deg):
                    return None
            if dip is not None:
                error = figures[prefix]["inclination_error_deg"] = estimate.inclination_deg - dip
                if _verdict_open(run, prefix + "inclination_error_deg", error, estimate.inclination_sigma_deg):
                    return None
        return figures

    return confirm
