"""What the line knows of a sensor's time skew before the unit is tumbled (:class:`SkewPrior`).

Why the line and not the unit: the skew is made by the firmware's message pipeline (PX4's
``sensor_mag`` older than the IMU time it travels with, ArduCopter's compass later than its message),
the same on every unit of a product on one link; the unit's tumble may or may not tell it apart from a
turned sensor (a two-axis gimbal at constant rates cannot).  So the product's ``time_skew`` says it
(measured, in the station file), or the station learns it from its own passing units of the part: each
unit's *own* skew (``time_skew_own_ms``, the tumble alone, recorded only where the tumble determined
it to :data:`OWN_SKEW_DETERMINED_MS`) — never the joined one, which would teach the line its own prior
back.

The prior for the next unit is the median of the last :data:`LEARN_WINDOW` such units, and its σ their
robust spread (at least :data:`SPREAD_FLOOR_MS`) widened for the median's own error: what one more
unit's skew may be off it, not the mean's precision (two runs of one PX4 build on one host read
−32.9 ± 0.7 and −23.4 ± 0.7 ms).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from magline.core.faults import StationFault
from magline.core.mounting.estimate import SkewPrior
from magline.core.station.schema import TimeSkew

if TYPE_CHECKING:
    from magline.core.sequencer.context import RunContext

LEARN_MIN_UNITS = 5  # fewer passing units with an own skew: nothing learnt yet
# A unit's own skew is recorded (and learnt from) only where its tumble determined it this well: on a
# two-axis gimbal the tumble says next to nothing (hundreds of ms), and such a value taught nothing.
OWN_SKEW_DETERMINED_MS = 10.0
LEARN_WINDOW = 30
SPREAD_FLOOR_MS = 1.0
OWN_SKEW = "time_skew_own_ms"


def learnt_prior(own_skews_ms: np.ndarray, where: str) -> SkewPrior | None:
    """The prior from earlier units' own skews (NaN: a unit whose tumble did not determine it)."""
    values = np.asarray(own_skews_ms, float)
    values = values[np.isfinite(values)]
    if len(values) < LEARN_MIN_UNITS:
        return None
    centre = float(np.median(values))
    spread = max(1.4826 * float(np.median(np.abs(values - centre))), SPREAD_FLOOR_MS)
    return SkewPrior(centre, spread * float(np.sqrt(1.0 + np.pi / (2.0 * len(values)))),
                     f"{len(values)} passing units {where}")


def skew_prior(run: RunContext, prefix: str) -> SkewPrior | None:
    """The prior for the sensor whose measurements carry ``prefix`` (cached for the run: the tumble's
    stop and the validate phase judge with the same one)."""
    if prefix not in run.skew_priors:
        run.skew_priors[prefix] = _find(run, prefix)
    return run.skew_priors[prefix]


def _find(run: RunContext, prefix: str) -> SkewPrior | None:
    from magline.core.results.contract import KeepsSeries  # on use: the results layer imports SQLAlchemy
    from magline.core.results.reading import RunFilter

    setting = run.product.time_skew
    if isinstance(setting, TimeSkew):
        return SkewPrior(setting.ms, setting.sigma_ms, "the station file")
    if setting == "none" or not isinstance(run.results, KeepsSeries):
        return None
    try:
        past = run.results.series(RunFilter(part=run.record.part, station_id=run.record.station_id, verdict="pass"),
                                  last=LEARN_WINDOW, names=[prefix + OWN_SKEW], with_limits=False)
    except StationFault as exc:
        run.log(f"the line's time skew is not known: {exc}")
        return None
    prior = learnt_prior(past.values.get(prefix + OWN_SKEW, np.array([])),
                         f"of {run.record.part} on station {run.record.station_id}")
    if prior is not None:
        run.log(f"{prefix.rstrip('.') or 'mag1'}: the line's time skew {prior.describe()}")
    return prior
