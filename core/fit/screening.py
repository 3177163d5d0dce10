"""Sample screening before the fit: non-finite rows, clipping at the sensor's range.

Why separate from the fit: every excluded sample must be counted with its reason, and the
reasons are decided by sensor facts (range, saturation), not by the estimator.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

# A saturated axis repeats its extreme value exactly; this many repeats (or 0.5 %) marks a plateau.
MIN_PLATEAU = 3


@dataclass
class Screening:
    keep: NDArray  # boolean mask over the input rows
    rejected: dict[str, int] = field(default_factory=dict)


def screen_samples(m: NDArray, range_ut: float | None) -> Screening:
    """Mask out non-finite samples and samples clipped at the sensor range.

    With ``range_ut`` given, any axis at or beyond 99.9 % of it is clipped.  Without it, an axis
    whose maximum (or minimum) value repeats as a plateau is taken as saturated there.
    """
    keep = np.all(np.isfinite(m), axis=1)
    rejected: dict[str, int] = {}
    if (~keep).any():
        rejected["non_finite"] = int((~keep).sum())
    clipped = np.zeros(len(m), dtype=bool)
    finite = m[keep]
    if range_ut is not None:
        clipped[keep] = np.any(np.abs(finite) >= 0.999 * range_ut, axis=1)
    elif len(finite):
        min_repeats = max(MIN_PLATEAU, int(0.005 * len(finite)))
        for axis in range(3):
            col = m[:, axis]
            for extreme in (finite[:, axis].max(), finite[:, axis].min()):
                at = keep & (col == extreme)
                if at.sum() >= min_repeats:
                    clipped |= at
    if clipped.any():
        rejected["clipped"] = int(clipped.sum())
    return Screening(keep=keep & ~clipped, rejected=rejected)


def planarity(x: NDArray) -> float:
    """√(λ_min/λ_max) of the sample scatter: ~0 when all samples lie in one plane (one rotation axis)."""
    if len(x) < 4:
        return 0.0
    w = np.linalg.eigvalsh(np.cov(x.T))
    return float(np.sqrt(max(w[0], 0.0) / w[-1])) if w[-1] > 0 else 0.0
