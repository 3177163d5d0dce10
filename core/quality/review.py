"""The in-run process review: is this passing unit typical of the recent units of its part?

A unit inside its absolute limits may still sit far outside what the process has been producing
(a magnetised screw lot, a new board revision).  Such a unit passes — the limits say it is good —
but engineering wants to look at it while it is still on the line.  Each numeric measurement is
compared with the same measurement of the last passing units of the same part on the same line:

* centre: the median; spread: σ = 1.4826 × MAD (the normal-consistent median absolute deviation,
  written with NumPy: scipy's ``median_abs_deviation`` gives the same figure at ten times the cost,
  which the unit would wait for), so that one bad unit in the window neither moves the centre nor
  widens the band;
* flagged when |value − median| > k·σ; the reason names the value, the distance in σ, the window
  and its centre;
* a measurement whose history has no spread (MAD 0: a count, a constant) is not judged, and the
  note says so — a zero σ would flag every change.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np

from magline.core.measurements import Numeric, Verdict
from magline.core.text import fmt

MAD_TO_SIGMA = 1.482602218505602  # 1 / Φ⁻¹(3/4): σ of a normal distribution from its MAD


@dataclass
class ReviewFlag:
    name: str
    value: float
    unit: str
    centre: float
    sigma: float
    z: float  # signed distance from the centre in σ
    units: int  # how many units the band came from
    reason: str

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class ReviewResult:
    flags: list[ReviewFlag]
    note: str  # what the unit was compared with, or why it was not


def review(measurements: Sequence[Numeric], history: dict[str, np.ndarray], *, units: int, min_units: int,
           sigma: float, exclude: Sequence[str] = (), what: str = "units") -> ReviewResult:
    """Flag the measurements outside median ± ``sigma``·σ of ``history`` (name → values of the
    last passing units).  ``units``: how many units the history holds; ``what`` names them in the
    note ("MOCK-100 units on line L1")."""
    if units < min_units:
        return ReviewResult([], f"no process review: {units} passing {what} in the store, {min_units} needed")
    flags: list[ReviewFlag] = []
    flat: list[str] = []
    for m in measurements:
        if m.name in exclude or m.verdict not in (Verdict.PASS, Verdict.REVIEW, Verdict.INFO):
            continue
        past = history.get(m.name)
        past = past[np.isfinite(past)] if past is not None else np.empty(0)
        if past.size < min_units or not np.isfinite(m.value):
            continue
        centre = float(np.median(past))
        spread = MAD_TO_SIGMA * float(np.median(np.abs(past - centre)))
        if spread <= 0.0:
            flat.append(m.name)
            continue
        z = (m.value - centre) / spread
        if abs(z) > sigma:
            side = "above" if z > 0 else "below"
            reason = (f"{m.name} {fmt(m.value, m.unit)} is {abs(z):.1f}σ {side} the last {past.size} units' "
                      f"median {fmt(centre, m.unit)} (σ {fmt(spread, m.unit)})")
            flags.append(ReviewFlag(m.name, float(m.value), m.unit, centre, spread, float(z), int(past.size), reason))
    note = f"compared with the last {units} passing {what} (median ± {sigma:g}σ, robust)"
    if flat:
        note += f"; not judged, no spread in the history: {', '.join(sorted(flat))}"
    return ReviewResult(flags, note)
