"""Whether a magnetometer caught warming up has settled: its offset no longer moves between attempts.

Why: a warm-up caught by the fit's drift test is measured again (``acquisition.retry_on_warm_up``),
but the next tumble may still fall inside the warm-up with a drift too small *within* it for the
drift test to see.  Calibrated there, the unit carries the offset of that moment, and the post-reboot
field check FAILed good units (−3.1 % against ±3 %, 2 of 25 benchmark runs of the simulators'
10 µT, τ 3 s warm-up).  Between two attempts the drift has had the whole gap to show itself, so the
attempt after a warm-up is accepted only where its offset agrees with the previous attempt's.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from magline.core.fit.quantiles import chi2_quantile

if TYPE_CHECKING:
    from magline.core.fit import FitResult


# the moved offset's statistic (χ² with 3 degrees of freedom) above this is not noise: p = 10⁻³,
# the drift test's own false-alarm rate
SETTLED_P_VALUE = 1e-3


def offset_moved(before: dict[int, FitResult], now: dict[int, FitResult], label: Callable[[int], str],
                 accepted_sigma_ut: Callable[[int], float]) -> str:
    """How far each magnetometer's offset moved from ``before`` (the attempt refused for a warm-up) to
    ``now``, in words, for those whose move is beyond both the two fits' noise (χ²₃ on their σ, at
    :data:`SETTLED_P_VALUE`) and ``accepted_sigma_ut(device_id)`` (the station's limit on the offset's
    σ: a move it would accept as uncertainty is no move); "" when every one has settled.
    ``label(device_id)`` names a sensor when there are several."""
    threshold = chi2_quantile(1.0 - SETTLED_P_VALUE, 3)
    moved = []
    for device_id, fit in now.items():
        earlier = before.get(device_id)
        if earlier is None:
            continue
        delta = np.asarray(fit.hard_iron_ut, float) - np.asarray(earlier.hard_iron_ut, float)
        variance = np.square(fit.hard_iron_sigma_ut) + np.square(earlier.hard_iron_sigma_ut)
        statistic = float(np.sum(np.square(delta) / np.maximum(variance, 1e-12)))
        distance = float(np.linalg.norm(delta))
        if statistic > threshold and distance > accepted_sigma_ut(device_id):
            words = f"the offset moved {distance:.1f} µT since the last attempt (still settling)"
            moved.append(f"{label(device_id)}: {words}" if len(now) > 1 else words)
    return "; ".join(moved)
