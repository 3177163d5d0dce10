"""Measurements, their limits and verdicts.

Why one module: the station file validates limit names against :data:`CATALOGUE`, the validate
phase produces these objects, the record stores them and the console shows them — one vocabulary.

Kinds: numeric (value + unit + limit), array (per-sample values whose aggregations — mean, std,
peak-to-peak — are validated like numerics, e.g. ``residual_ut.std``), JSON (coefficients written)
and attachments (raw samples CSV).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from enum import StrEnum
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from magline.core.station.schema import Limit


class Verdict(StrEnum):
    """A measurement's verdict against its limit: PASS inside it, REVIEW inside but within its marginal
    band (or flagged by the process review: the unit passes, an engineer looks), FAIL outside (the unit is
    bad), INFO where no limit is declared (recorded, never judged)."""

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
    "rejected_fraction": ("", "share of samples judged bad and excluded (clipped, spikes)"),
    "warm_up_fraction": ("", "share of the earliest samples left out because the offset was still drifting"),
    "drift_detectable_ut": ("µT", "warm-up drift of the offset that could pass the drift test unseen"),
    "attempts": ("", "acquisition attempts needed"),
    "misalignment_deg": ("°", "sensor axes rotated against the coil frame (Helmholtz affine fit only)"),
    "model_misfit_deg": ("°", "heading cost of the diagonal / sphere model the autopilot holds, against "
                              "the full soft iron (only when the full model fits significantly better)"),
    "orientation": ("", "the firmware orientation value the sensor is really mounted in (must be the configured one)"),
    "mounting_error_deg": ("°", "sensor axes against the nearest firmware orientation, from gravity and the field"),
    "mounting_sigma_deg": ("°", "1σ uncertainty of the mounting estimate"),
    "inclination_deg": ("°", "field inclination the unit saw (angle between gravity and the calibrated field)"),
    "time_skew_ms": ("ms", "how much later than its message's time stamp a magnetometer reading was taken, on the "
                           "accelerometer's clock (negative: earlier)"),
    "time_skew_sigma_ms": ("ms", "1σ uncertainty of the time skew"),
    "time_skew_own_ms": ("ms", "the time skew as this unit's tumble alone says it, before the line's known skew "
                               "is joined with it (what the line learns its skew from)"),
    "time_skew_own_sigma_ms": ("ms", "1σ uncertainty of the unit's own time skew (absent: its tumble could not "
                                     "tell the skew from a turned sensor)"),
    "inclination_error_deg": ("°", "field inclination the unit saw minus the reference's"),
    "heading_agreement_median_deg": ("°", "median heading difference between two calibrated magnetometers"),
    "heading_agreement_max_deg": ("°", "largest heading difference between two magnetometers (over the tumble)"),
    "interference_pct_at_max": ("%", "field the power wiring's current adds at the compass at the product's "
                                     "current_max_a, as a share of the local field (ArduPilot: < 30 fine, 30–60 "
                                     "grey, > 60 move the compass)"),
    "interference_ut_per_a": ("µT/A", "field change at the compass per amp of the unit's current (length)"),
    "interference_sigma_ut_per_a": ("µT/A", "1σ uncertainty of the field change per amp"),
    "interference_linearity_ut": ("µT", "largest departure of a sweep step from the straight line in the current"),
    "interference_return_ut": ("µT", "field left changed once the current is back at zero (a magnetised part)"),
    "interference_left_pct_at_max": ("%", "after compensation, proven after the power cycle: what the firmware's "
                                          "corrected field still changes at current_max_a, as a share of the field"),
    "current_sensor_error_pct": ("%", "the unit's own current reading against the load's measured current"),
}
# The values a measurement can take at all: a limit outside them is a station-file mistake (every unit
# would fail, or the limit would never bite), caught by ``magline check``.
POSSIBLE: dict[str, tuple[float, float]] = {
    "hard_iron_norm_ut": (0.0, float("inf")), "hard_iron_sigma_ut": (0.0, float("inf")),
    "axis_ratio": (1.0, float("inf")), "soft_iron_offdiag_max": (0.0, float("inf")),
    "residual_rms_ut": (0.0, float("inf")), "residual_max_ut": (0.0, float("inf")), "field_ut": (0.0, float("inf")),
    "coverage": (0.0, 1.0), "direction_sigma_deg": (0.0, float("inf")), "rejected_fraction": (0.0, 1.0),
    "attempts": (1.0, float("inf")), "warm_up_fraction": (0.0, 1.0), "misalignment_deg": (0.0, 180.0),
    "drift_detectable_ut": (0.0, float("inf")),
    "model_misfit_deg": (0.0, 180.0),
    "mounting_error_deg": (0.0, 180.0), "mounting_sigma_deg": (0.0, float("inf")),
    "inclination_deg": (-90.0, 90.0), "inclination_error_deg": (-180.0, 180.0),
    "time_skew_ms": (-float("inf"), float("inf")), "time_skew_sigma_ms": (0.0, float("inf")),
    "time_skew_own_ms": (-float("inf"), float("inf")), "time_skew_own_sigma_ms": (0.0, float("inf")),
    "heading_agreement_median_deg": (0.0, 180.0), "heading_agreement_max_deg": (0.0, 180.0),
    "residual_ut.std": (0.0, float("inf")), "residual_ut.ptp": (0.0, float("inf")),
    "interference_pct_at_max": (0.0, float("inf")), "interference_ut_per_a": (0.0, float("inf")),
    "interference_sigma_ut_per_a": (0.0, float("inf")), "interference_linearity_ut": (0.0, float("inf")),
    "interference_return_ut": (0.0, float("inf")), "interference_left_pct_at_max": (0.0, float("inf")),
    "current_sensor_error_pct": (-100.0, float("inf")),
}
# Limits that apply when a station file declares none (the mounting and agreement checks of issue 26).
DEFAULT_LIMITS: dict[str, dict[str, Any]] = {
    "mounting_error_deg": {"le": 3.0},
    "inclination_error_deg": {"range": [-2.0, 2.0]},
    "heading_agreement_median_deg": {"le": 1.0},
    "heading_agreement_max_deg": {"le": 3.0},
    # issue 46: ArduPilot's bands for the interference (> 60 % move the compass; 30–60 % grey: review), a
    # power module's scale within 5 %, a magnetised part or a bent line of more than 1 µT, and what
    # compensation leaves at the top current
    "interference_pct_at_max": {"le": 60.0, "marginal": 30.0},
    "current_sensor_error_pct": {"range": [-5.0, 5.0]},
    "interference_return_ut": {"le": 1.0},
    "interference_linearity_ut": {"le": 1.0},
    "interference_left_pct_at_max": {"le": 5.0},
}
# ``mag2.hard_iron_x_ut``: compass 2's measurement; ``mag1-mag3.heading_agreement_max_deg``: a pair's.
# The primary magnetometer's measurements carry no prefix (the names every station had before).
SENSOR_PREFIX = re.compile(r"^(mag[1-9])(?:-(mag[1-9]))?\.")
ARRAY_MEASUREMENTS: dict[str, str] = {"residual_ut": "µT"}
AGGREGATIONS = ("mean", "std", "ptp")
KNOWN_LIMIT_NAMES = frozenset(CATALOGUE) | {f"{a}.{g}" for a in ARRAY_MEASUREMENTS for g in AGGREGATIONS}
DECLARED_NAME = re.compile(r"^[a-z][a-z0-9_]*$")


# What the loaded plugins' own measurements mean, in their words (name → meaning): what the operator's
# screen and console say of one that failed, as they say the catalogue's meaning of magline's.  Only words:
# whether a station may limit a name is decided by the plugins a station file is read with, never here.
DECLARED_MEANINGS: dict[str, str] = {}


@dataclass(frozen=True)
class DeclaredMeasurement:
    """A plugin's own measurement, declared through ``magline_register_measurements``: a station file may
    limit it like one of magline's (``limits: {acme_board_temp_c: {le: 60}}``), and the limit is checked,
    hashed into the limit set, judged, stored, charted by ``magline spc`` and exported like theirs.

    ``possible``: the values it can take at all (a limit outside them is a station-file mistake)."""

    name: str
    unit: str
    meaning: str
    possible: tuple[float, float]
    plugin: str

    def problem(self) -> str | None:
        """Why this declaration cannot be taken (None: it can)."""
        if not isinstance(self.name, str) or not DECLARED_NAME.match(self.name):
            return (f"measurement name {self.name!r} must be lower-case letters, digits and underscores "
                    "(a sensor's prefix mag2. is added by magline)")
        if self.name in KNOWN_LIMIT_NAMES:
            return f"measurement {self.name!r} is magline's own: a plugin declares names of its own (prefix them)"
        low, high = self.possible
        if not low <= high:
            return f"measurement {self.name!r}: possible must be (low, high) with low <= high"
        return None


def base_name(name: str) -> str:
    """The catalogue name of a sensor's or a pair's measurement (``mag2.axis_ratio`` → ``axis_ratio``)."""
    return SENSOR_PREFIX.sub("", name)


def by_sensor(measured: list[Measurement]) -> dict[str, list[Measurement]]:
    """Measurements grouped by sensor prefix (``""`` the primary, ``mag2.``, then pairs ``mag1-mag2.``),
    in the order they were measured: the console's sections and the screen's cards per compass."""
    groups: dict[str, list[Measurement]] = {}
    for m in measured:
        groups.setdefault(m.name[: len(m.name) - len(base_name(m.name))], []).append(m)
    return groups


def known_limit_name(name: str) -> bool:
    return base_name(name) in KNOWN_LIMIT_NAMES


def limit_for(name: str, limits: dict[str, Limit]) -> Limit | None:
    """A sensor's own limit (``mag2.x``) where the station declares one, else the line's (``x``)."""
    return limits.get(name) or limits.get(base_name(name))


def judge(value: float, limit: Limit | None) -> Verdict:
    """Pass / review / fail of a value against a limit (review = within the marginal band)."""
    if limit is None:
        return Verdict.INFO
    if not math.isfinite(value):
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
    """One figure of a unit with its limit and verdict — what a station file limits, ``spc`` charts and
    ``export`` writes.  Make one with :meth:`Numeric.of`, which looks its unit up and judges it against the
    station's limits."""

    name: str
    value: float
    unit: str = ""
    low: float | None = None
    high: float | None = None
    verdict: Verdict = Verdict.INFO

    note: str = ""  # the failure in the operator's words, where the name and limit alone say too little

    @classmethod
    def of(cls, name: str, value: float, limits: dict[str, Limit], unit: str | None = None) -> Numeric:
        limit = limit_for(name, limits)
        return cls(name=name, value=float(value), unit=CATALOGUE.get(base_name(name), (unit or "", ""))[0],
                   low=limit.low if limit else None, high=limit.high if limit else None,
                   verdict=judge(float(value), limit))

    def rejudged(self, name: str, limits: dict[str, Limit]) -> Numeric:
        """The same figure under another name (a sensor's prefix), judged against that name's limit."""
        return Numeric(name=name, value=self.value, unit=self.unit, note=self.note,
                       **_judged(self.value, limit_for(name, limits)))


@dataclass
class Array:
    """Per-sample values (chart data) with validated aggregations."""

    name: str
    values: list[float]
    unit: str = ""
    aggregations: list[Numeric] = field(default_factory=list)

    @classmethod
    def of(cls, name: str, values: Any, limits: dict[str, Limit]) -> Array:
        import numpy as np  # here: numpy is not needed to start a command

        arr = np.asarray(values, float)
        aggs = {"mean": arr.mean(), "std": arr.std(ddof=1) if arr.size > 1 else 0.0, "ptp": np.ptp(arr)}
        unit = ARRAY_MEASUREMENTS.get(name, "")
        numerics = []
        for agg, value in aggs.items():
            n = Numeric.of(f"{name}.{agg}", value, limits)
            n.unit = unit
            numerics.append(n)
        return cls(name=name, values=[float(v) for v in arr], unit=unit, aggregations=numerics)


def _judged(value: float, limit: Limit | None) -> dict[str, Any]:
    return {"low": limit.low if limit else None, "high": limit.high if limit else None,
            "verdict": judge(value, limit)}


def prefixed(measurements: list[Measurement], prefix: str, limits: dict[str, Limit]) -> list[Measurement]:
    """One sensor's measurements under its prefix (``mag2.``), each judged against that sensor's limit."""
    out: list[Measurement] = []
    for m in measurements:
        if isinstance(m, Numeric):
            out.append(m.rejudged(prefix + m.name, limits))
        elif isinstance(m, Array):
            out.append(Array(name=prefix + m.name, values=m.values, unit=m.unit,
                             aggregations=[a.rejudged(prefix + a.name, limits) for a in m.aggregations]))
        else:
            out.append(Json(name=prefix + m.name, data=m.data))
    return out


@dataclass
class Json:
    """Structured data kept with the record as it is (a report of the mounting, the parameters written):
    never judged, never charted."""

    name: str
    data: Any


@dataclass
class Attachment:
    name: str
    mime: str
    content: bytes


Measurement = Numeric | Array | Json  # what a validate hook returns: figures, per-sample data, structured data


def verdicts(measurements: list[Measurement]) -> list[Numeric]:
    """Every numeric figure that carries a verdict, aggregations included."""
    out: list[Numeric] = []
    for m in measurements:
        if isinstance(m, Numeric):
            out.append(m)
        elif isinstance(m, Array):
            out.extend(m.aggregations)
    return out
