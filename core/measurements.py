"""Measurements, their limits and verdicts.

Why one module: the station file validates limit names against :data:`CATALOGUE`, the validate
phase produces these objects, the record stores them and the console shows them — one vocabulary.

Kinds: numeric (value + unit + limit), array (per-sample values whose aggregations — mean, std,
peak-to-peak — are validated like numerics, e.g. ``residual_ut.std``), JSON (coefficients written)
and attachments (raw samples CSV).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from magline.core.station.schema import Limit


class Verdict(StrEnum):
    PASS = "pass"
    REVIEW = "review"  # inside the limit but within its marginal band
    FAIL = "fail"
    INFO = "info"  # no limit declared


# name -> (unit, meaning).  Limits may be declared for any of these.
CATALOGUE: dict[str, tuple[str, str]] = {
    "hard_iron_x_ut": ("µT", "hard-iron offset, x"),
    "hard_iron_y_ut": ("µT", "hard-iron offset, y"),
    "hard_iron_z_ut": ("µT", "hard-iron offset, z"),
    "hard_iron_norm_ut": ("µT", "length of the hard-iron offset"),
    "hard_iron_sigma_ut": ("µT", "1σ uncertainty of the offset (length)"),
    "axis_ratio": ("", "soft-iron sphericity: largest / smallest axis (1 = sphere)"),
    "soft_iron_offdiag_max": ("", "largest off-diagonal soft-iron term"),
    "residual_rms_ut": ("µT", "RMS of |m_cal| − field"),
    "residual_max_ut": ("µT", "largest |m_cal| − field"),
    "field_ut": ("µT", "radius of the calibrated sphere"),
    "field_error_pct": ("%", "raw field estimate vs the reference field"),
    "coverage": ("", "fraction of direction bins covered"),
    "direction_sigma_deg": ("°", "predicted 1σ heading error over the orientations seen"),
    "rejected_fraction": ("", "share of samples excluded (clipped, spikes)"),
    "attempts": ("", "acquisition attempts needed"),
    "misalignment_deg": ("°", "sensor axes rotated against the coil frame (Helmholtz affine fit only)"),
    "model_misfit_deg": ("°", "heading cost of the diagonal / sphere model the autopilot holds, against "
                              "the full soft iron (only when the full model fits significantly better)"),
}
ARRAY_MEASUREMENTS: dict[str, str] = {"residual_ut": "µT"}
AGGREGATIONS = ("mean", "std", "ptp")
KNOWN_LIMIT_NAMES = frozenset(CATALOGUE) | {f"{a}.{g}" for a in ARRAY_MEASUREMENTS for g in AGGREGATIONS}


def judge(value: float, limit: Limit | None) -> Verdict:
    """Pass / review / fail of a value against a limit (review = within the marginal band)."""
    if limit is None:
        return Verdict.INFO
    if not np.isfinite(value):
        return Verdict.FAIL
    low, high = limit.low, limit.high
    if (low is not None and value < low) or (high is not None and value > high):
        return Verdict.FAIL
    band = limit.marginal or 0.0
    if band and ((low is not None and value < low + band) or (high is not None and value > high - band)):
        return Verdict.REVIEW
    return Verdict.PASS


@dataclass
class Numeric:
    name: str
    value: float
    unit: str = ""
    low: float | None = None
    high: float | None = None
    verdict: Verdict = Verdict.INFO

    @classmethod
    def of(cls, name: str, value: float, limits: dict[str, Limit], unit: str | None = None) -> Numeric:
        limit = limits.get(name)
        return cls(name=name, value=float(value), unit=CATALOGUE.get(name, (unit or "", ""))[0],
                   low=limit.low if limit else None, high=limit.high if limit else None,
                   verdict=judge(float(value), limit))


@dataclass
class Array:
    """Per-sample values (chart data) with validated aggregations."""

    name: str
    values: list[float]
    unit: str = ""
    aggregations: list[Numeric] = field(default_factory=list)

    @classmethod
    def of(cls, name: str, values: Any, limits: dict[str, Limit]) -> Array:
        arr = np.asarray(values, float)
        aggs = {"mean": arr.mean(), "std": arr.std(ddof=1) if arr.size > 1 else 0.0, "ptp": np.ptp(arr)}
        unit = ARRAY_MEASUREMENTS.get(name, "")
        numerics = []
        for agg, value in aggs.items():
            n = Numeric.of(f"{name}.{agg}", value, limits)
            n.unit = unit
            numerics.append(n)
        return cls(name=name, values=[float(v) for v in arr], unit=unit, aggregations=numerics)


@dataclass
class Json:
    name: str
    data: Any


@dataclass
class Attachment:
    name: str
    mime: str
    content: bytes


Measurement = Numeric | Array | Json


def verdicts(measurements: list[Measurement]) -> list[Numeric]:
    """Every numeric figure that carries a verdict, aggregations included."""
    out: list[Numeric] = []
    for m in measurements:
        if isinstance(m, Numeric):
            out.append(m)
        elif isinstance(m, Array):
            out.extend(m.aggregations)
    return out
