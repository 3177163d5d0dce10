"""Is a characteristic normal?  Anderson–Darling, as Minitab's capability analysis asks it.

Why Anderson–Darling: it weighs the tails, which is where a capability index lives (a Cpk is a
statement about the 0.135 % beyond 3σ).  scipy computes the statistic with the mean and σ estimated
from the data and interpolates its p-value in Stephens' tables, which span 0.01 … 0.15: a p-value at
an end is said as a bound ("≤ 0.01", "≥ 0.15"), never as a number the table does not hold.  The
decision at 0.05 lies well inside them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

ALPHA = 0.05  # below this p-value the normal model is rejected
MIN_VALUES = 8  # Stephens' tables for the estimated-parameter case start here
TABLE_P = (0.01, 0.15)  # the p-values scipy's interpolation can return, ends included


@dataclass(frozen=True)
class Normality:
    statistic: float  # A²
    p: float
    n: int

    @property
    def normal(self) -> bool:
        return self.p >= ALPHA

    @property
    def p_words(self) -> str:
        """The p-value as the table allows saying it."""
        if self.p <= TABLE_P[0]:
            return f"≤ {TABLE_P[0]:g}"
        if self.p >= TABLE_P[1]:
            return f"≥ {TABLE_P[1]:g}"
        return f"{self.p:.3f}"

    def to_dict(self) -> dict:
        return {"test": "Anderson-Darling", "statistic": self.statistic, "p": self.p, "p_words": self.p_words,
                "n": self.n, "normal": self.normal}


def anderson_darling(values: np.ndarray) -> Normality | None:
    """The test on ``values`` (NaN left out); None below :data:`MIN_VALUES` or for a constant."""
    from scipy import stats  # imported on use: scipy.stats costs a second of every command's start

    x = np.asarray(values, dtype=float)
    x = x[np.isfinite(x)]
    if x.size < MIN_VALUES or np.ptp(x) == 0:
        return None
    result = stats.anderson(x, dist="norm", method="interpolate")
    return Normality(statistic=float(result.statistic), p=float(result.pvalue), n=int(x.size))
