"""Western Electric / Nelson run rules on an individuals chart.

Written here (vectorised with NumPy) because no maintained Python statistics library implements
them: scipy and statsmodels have no control-chart rules, and the SPC packages on PyPI are
unmaintained.  Each rule is tested on the window that ends at each point; the point that completes
the pattern carries the signal, so the first signal of a rule is when an engineer could have known.

Per-point false-alarm probability of each rule for an in-control normal process with known centre
and σ (what the tests check the implementation against):

========================  =========================================  ===========
rule                      pattern (window ending at the point)       probability
========================  =========================================  ===========
``beyond_3sigma``         the point beyond 3σ                        0.00270
``2_of_3_beyond_2sigma``  ≥ 2 of the last 3 beyond 2σ, same side     0.00306
``4_of_5_beyond_1sigma``  ≥ 4 of the last 5 beyond 1σ, same side     0.00553
``8_on_one_side``         the last 8 on the same side of the centre  0.00781
``6_trending``            the last 6 strictly rising or falling      0.00278
========================  =========================================  ===========
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

RULES: dict[str, str] = {
    "beyond_3sigma": "1 point beyond 3σ",
    "2_of_3_beyond_2sigma": "2 of 3 points beyond 2σ on one side",
    "4_of_5_beyond_1sigma": "4 of 5 points beyond 1σ on one side",
    "8_on_one_side": "8 points in a row on one side of the centre line",
    "6_trending": "6 points in a row steadily rising or falling",
}


@dataclass(frozen=True)
class Signal:
    rule: str  # a key of RULES
    point: int  # index of the point that completes the pattern (in the chart's values)


def _k_of_n(flags: np.ndarray, k: int, n: int) -> np.ndarray:
    """Per point: at least ``k`` of the ``n`` flags in the window ending there are set."""
    out = np.zeros(flags.size, dtype=bool)
    if flags.size >= n:
        out[n - 1:] = sliding_window_view(flags.astype(int), n).sum(axis=1) >= k
    return out


def rule_hits(x: np.ndarray, centre: float, sigma: float) -> dict[str, np.ndarray]:
    """Per rule, a boolean per point: the window ending at that point shows the pattern."""
    z = (np.asarray(x, dtype=float) - centre) / sigma
    hits = {"beyond_3sigma": np.abs(z) > 3}
    hits["2_of_3_beyond_2sigma"] = _k_of_n(z > 2, 2, 3) | _k_of_n(z < -2, 2, 3)
    hits["4_of_5_beyond_1sigma"] = _k_of_n(z > 1, 4, 5) | _k_of_n(z < -1, 4, 5)
    hits["8_on_one_side"] = _k_of_n(z > 0, 8, 8) | _k_of_n(z < 0, 8, 8)
    steps = np.diff(z)
    rising = np.concatenate([[False], _k_of_n(steps > 0, 5, 5)])
    falling = np.concatenate([[False], _k_of_n(steps < 0, 5, 5)])
    hits["6_trending"] = rising | falling
    return hits


def evaluate(x: np.ndarray, centre: float, sigma: float) -> list[Signal]:
    """Every signal, in point order (a point may carry several rules)."""
    hits = rule_hits(x, centre, sigma)
    found = [Signal(rule, int(i)) for rule, flags in hits.items() for i in np.flatnonzero(flags)]
    return sorted(found, key=lambda s: (s.point, list(RULES).index(s.rule)))
