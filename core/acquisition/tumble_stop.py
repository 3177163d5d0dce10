"""When a tumble is enough (``acquisition.stop: determined``): the running fit's rule built from the
station's limits, the mounting's σ targets, and the stall of a tumble that stopped covering new
directions.  The acquire phase (:mod:`magline.core.acquisition.tumble`) asks; the rule itself and the fit beside
the stream are :mod:`magline.core.fit.running`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

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
    """A tumble whose coverage stopped growing short of its target: no new direction over the last
    two thirds of its readings (at least ``min_samples`` of them).  Reading on cannot reach the
    target, so a determined tumble ends there and the operator is asked again at once (a spin about
    one axis covers its ring in one turn, then repeats it).

    Why two thirds, not half: a turn there and back retraces exactly as long as it went before it
    reaches new directions, so at half the rule fired the moment such a motion went on to new ones
    (10 % of the PX4 simulator's tumbles at 50 Hz, their readings thrown away and the operator asked
    again).  A ring is covered in its first turn, so a spin still stalls at ``2 × min_samples``; one
    whose wobble finds a new direction now and then stalls later than at half (``benchmarks/stall.py``).
    Not so since the coverage stopped lighting bins about a "sphere" under 10 µT (issue 49): a ring's
    coverage now creeps as its ill-determined centre moves, and a spin stalls at a median ~940 readings
    (docs/station-file.md, *Stop tumbling when the calibration is determined*)."""

    WITHOUT_GROWTH = 2 / 3  # the share of the readings with no new direction that is a stall

    def __init__(self, min_samples: int, target: float) -> None:
        self.min_samples, self.target = min_samples, target
        self.history: list[tuple[int, float]] = []  # (readings, coverage) at each change of coverage

    def stalled(self, count: int, coverage: float) -> bool:
        if not self.history or coverage > self.history[-1][1]:
            self.history.append((count, coverage))
        since = self.history[-1][0]  # readings when the coverage last grew
        return coverage < self.target and count >= 2 * self.min_samples and count - since >= max(
            self.min_samples, self.WITHOUT_GROWTH * count)


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
                estimate = estimate_mounting(calibrated(fit, samples.mag_ut), samples.t_ms, imu,
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
