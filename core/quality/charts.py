"""Individuals and moving-range (I-MR) control charts: one unit is one subgroup of one.

Why I-MR: a calibration line measures every unit once, so there are no rational subgroups; the
within-process spread is estimated from consecutive units (σ = MR̄ / d₂, d₂ = 1.128 for ranges of
two), which a drift between units does not inflate the way the overall standard deviation does.
Centre line and limits come from a baseline window (the first ``baseline`` units of the selection)
and are then held, so that later units are judged against the process as it was.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from magline.core.quality.rules import Signal, evaluate

D2 = 1.128  # E[range of two normal values] / σ
D4 = 3.267  # upper limit of the moving-range chart: D4 · MR̄


def control_limits(centre: float, sigma: float, bounds: tuple[float, float] = (-np.inf, np.inf)) -> tuple[float, float]:
    """(LCL, UCL) at 3σ, kept inside what the measurement can take: an angle's or a length's LCL is never
    below 0 — a limit no unit can cross signals nothing and only misleads the reader."""
    return max(centre - 3 * sigma, bounds[0]), min(centre + 3 * sigma, bounds[1])


@dataclass
class ImrChart:
    name: str
    values: np.ndarray  # the individual values, oldest first (NaN removed)
    index: np.ndarray  # position of each value in the run selection (to name the unit)
    centre: float
    sigma: float  # within-process σ = MR̄ / d₂ from the baseline
    mr_bar: float
    baseline: int  # how many points set the centre and the limits
    signals: list[Signal] = field(default_factory=list)
    bounds: tuple[float, float] = (-np.inf, np.inf)  # what the measurement can take (a fraction: [0, 1])
    in_baseline: np.ndarray | None = None  # which values set the centre and the limits (``baseline`` of them)

    @property
    def ucl(self) -> float:
        return control_limits(self.centre, self.sigma, self.bounds)[1]

    @property
    def lcl(self) -> float:
        return control_limits(self.centre, self.sigma, self.bounds)[0]

    @property
    def mr_ucl(self) -> float:
        return D4 * self.mr_bar

    @property
    def moving_ranges(self) -> np.ndarray:
        return np.abs(np.diff(self.values))


def imr_chart(name: str, values: np.ndarray, baseline: int = 50, outside: np.ndarray | None = None,
              bounds: tuple[float, float] = (-np.inf, np.inf)) -> ImrChart | None:
    """The chart of ``values`` (NaN skipped), its limits from the first ``baseline`` points, and
    the rule signals over every point; None when fewer than three values exist.  ``outside`` marks
    units that failed the measurement's own limits: they are plotted and signalled as themselves,
    but never set the centre line (one failed unit would otherwise move it and raise a run of false
    "8 on one side" signals on every good unit after it)."""
    values = np.asarray(values, dtype=float)
    index = np.flatnonzero(np.isfinite(values))
    x = values[index]
    if x.size < 3:
        return None
    failed = np.zeros(values.size, bool) if outside is None else np.asarray(outside, bool)
    window = max(3, min(baseline, x.size))
    chosen = np.zeros(x.size, bool)
    chosen[:window] = True
    if np.count_nonzero(chosen & ~failed[index]) >= 3:
        chosen &= ~failed[index]
    base = x[chosen]
    centre = float(base.mean())
    mr_bar = float(np.abs(np.diff(base)).mean())
    sigma = mr_bar / D2
    chart = ImrChart(name=name, values=x, index=index, centre=centre, sigma=sigma, mr_bar=mr_bar, baseline=base.size,
                     bounds=bounds, in_baseline=chosen)
    chart.signals = evaluate(x, centre, sigma) if sigma > 0 else []
    return chart


def frozen_chart(name: str, values: np.ndarray, centre: float, sigma: float, mr_bar: float,
                 bounds: tuple[float, float] = (-np.inf, np.inf)) -> ImrChart | None:
    """The chart of ``values`` against limits a baseline froze earlier (AIAG Phase II): nothing in this
    window moves them, every point is judged by the rules; None without values.  Which of the window's
    points came from the baseline is the caller's to mark (it knows the runs)."""
    values = np.asarray(values, dtype=float)
    index = np.flatnonzero(np.isfinite(values))
    x = values[index]
    if x.size == 0:
        return None
    chart = ImrChart(name=name, values=x, index=index, centre=centre, sigma=sigma, mr_bar=mr_bar, baseline=0,
                     bounds=bounds, in_baseline=np.zeros(x.size, bool))
    chart.signals = evaluate(x, centre, sigma) if sigma > 0 else []
    return chart
