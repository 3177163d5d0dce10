"""Process capability against the station's limits: Cpk (within-process σ) and Ppk (overall σ),
with confidence intervals — so that limits can be tightened once the process is known.

* Cpk = min(USL − μ, μ − LSL) / 3σ_within, σ_within = MR̄ / d₂ (the I-MR chart's);
* Ppk = the same with the overall sample standard deviation;
* a one-sided limit gives the one-sided index (CPU or CPL);
* confidence interval: Bissell's normal approximation (1990),
  Ĉ ± z₁₋α/₂ · √(1/(9n) + Ĉ²/(2(n − 1))), for both indices.

Written here because no maintained Python library computes them; the normal quantile is the
standard library's ``statistics.NormalDist`` (scipy.stats would add a second to every start).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np


@dataclass(frozen=True)
class Index:
    value: float
    low: float  # confidence interval
    high: float


@dataclass(frozen=True)
class Capability:
    n: int
    mean: float
    sigma_within: float
    sigma_overall: float
    cpk: Index | None
    ppk: Index | None


# Fewer judged units than this and no capability is stated: AIAG's SPC manual (2nd ed.) asks 25 subgroups
# before limits are computed at all; a Cpk from three units (once printed as 1388 [27.8, 2750]) is noise.
MIN_UNITS = 25
MIN_UNITS_SOURCE = "AIAG SPC manual: 25 subgroups"


def _index(mean: float, sigma: float, low: float | None, high: float | None, n: int,
           confidence: float, min_units: int) -> Index | None:
    if sigma <= 0 or n < max(min_units, 2) or (low is None and high is None):
        return None
    sides = [(high - mean) / (3 * sigma)] if high is not None else []
    sides += [(mean - low) / (3 * sigma)] if low is not None else []
    value = min(sides)
    z = NormalDist().inv_cdf(0.5 + confidence / 2)
    half = z * math.sqrt(1 / (9 * n) + value ** 2 / (2 * (n - 1)))
    return Index(value, value - half, value + half)


def capability(values: np.ndarray, low: float | None, high: float | None, sigma_within: float,
               confidence: float = 0.95, min_units: int = MIN_UNITS) -> Capability:
    """Cpk / Ppk with their intervals; None for an index below ``min_units`` values (see MIN_UNITS)."""
    x = np.asarray(values, dtype=float)
    x = x[np.isfinite(x)]
    mean = float(x.mean()) if x.size else math.nan
    overall = float(x.std(ddof=1)) if x.size > 1 else 0.0
    return Capability(n=int(x.size), mean=mean, sigma_within=sigma_within, sigma_overall=overall,
                      cpk=_index(mean, sigma_within, low, high, x.size, confidence, min_units),
                      ppk=_index(mean, overall, low, high, x.size, confidence, min_units))
