"""What a fit returns, what it is told, and how it refuses.

Why explicit types: the sequencer, the validators, the record and the `magline fit --json` output
all read the same figures; a dataclass with unit-suffixed names is the contract between them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from magline.core.fit.model import SoftIronModel
    from magline.core.fit.radial import RadialUncertainty



class FitRefused(ValueError):
    """The data cannot determine the calibration; ``advice`` tells the operator what to do."""

    def __init__(self, reason: str, message: str, advice: str) -> None:
        super().__init__(f"{message} — {advice}")
        self.reason = reason
        self.message = message
        self.advice = advice


def warm_up_words(drift: dict | None) -> str:
    """What the drift test caught (its ``drift`` dict), in words; "" when it caught nothing."""
    drift = drift or {}
    if drift.get("modelled"):
        return "the offset drifted through the tumble (the drift modelled)"
    if drift.get("warm_up_excluded"):
        return f"the offset drifted early in the tumble (the first {drift['warm_up_excluded']} readings set aside)"
    if drift.get("unresolved"):
        return "the offset drifted, and the drift could be neither set aside nor modelled"
    return ""


@dataclass(frozen=True)
class FitOptions:
    """Tunable behaviour of :func:`magline.core.fit.fit_calibration`.

    ``gain_sigma`` is the prior 1σ of the raw-to-reference field ratio (sensor gain and
    volume change of the soft iron): with a reference field it pins the overall scale, which is
    what sharpens partial-coverage fits; with full coverage the data dominate it.
    """

    model: SoftIronModel = "full"
    field_ut: float | None = None
    range_ut: float | None = None
    coverage_bins: int = 100
    gain_sigma: float = 0.05
    shape_sigma: float = 0.15
    outlier_sigmas: float = 5.0
    max_outlier_fraction: float = 0.3
    max_offset_sigma_fraction: float = 0.25
    max_direction_sigma_deg: float = 1.0
    max_residual_fraction: float = 0.05
    min_planarity: float = 0.15
    max_axis_ratio: float = 2.0
    drift_p_value: float = 1e-3
    debias: bool = True
    # each reading is the mean of the driver's samples, taken this often (Hz), since the reading before it
    # (ArduPilot's compass: since the vehicle last read it); 0: each reading is one sample
    sample_rate_hz: float = 0.0


@dataclass
class FitResult:
    """A calibration such that ``soft_iron @ (m − hard_iron_ut)`` lies on a sphere of ``field_ut``."""

    model: SoftIronModel | Literal["affine"]
    hard_iron_ut: NDArray
    soft_iron: NDArray
    field_ut: float
    field_estimate_ut: float
    field_sigma_ut: float
    reference_field_ut: float | None
    raw_to_reference_ratio: float | None
    raw_to_reference_sigma: float | None
    hard_iron_sigma_ut: NDArray
    soft_iron_sigma: NDArray
    residuals_ut: NDArray  # |m_cal| − field_ut per used sample
    used: NDArray  # boolean mask over the input rows
    samples_total: int
    rejected: dict[str, int]
    coverage: float
    coverage_bins: int
    planarity: float
    condition_number: float
    direction_sigma_deg: float
    drift: dict[str, Any] | None = None
    noise_ut: float = 0.0
    bias_correction: dict[str, Any] | None = None  # what the second-order correction did, if it ran
    # set when a diagonal / sphere model cannot represent the unit's soft iron (see geometric.py)
    model_misfit: dict[str, Any] | None = None
    # the window each reading averaged over (``window_s``) and how far the fit moved the readings for it (µT)
    reading_window: dict[str, Any] | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    # the radial σ in any direction (geometric fits; None for a coil's affine fit)
    radial: RadialUncertainty | None = field(default=None, repr=False, compare=False)

    @property
    def samples_used(self) -> int:
        return int(self.used.sum())

    @property
    def residual_rms_ut(self) -> float:
        return float(np.sqrt(np.mean(self.residuals_ut**2)))

    @property
    def residual_max_ut(self) -> float:
        return float(np.max(np.abs(self.residuals_ut)))

    @property
    def axis_ratio(self) -> float:
        """Largest over smallest eigenvalue of the soft-iron matrix (1 = no soft iron)."""
        w = np.linalg.eigvalsh(self.soft_iron)
        return float(w[-1] / w[0])

    @property
    def warm_up_caught(self) -> str:
        """What the warm-up drift test caught in these readings, in words ("" when nothing): readings
        set aside, the drift modelled, or a drift found that could be neither.  Why it matters: such a
        fit is the offset *during* the warm-up, and the sensor goes on settling after it."""
        return warm_up_words(self.drift)

    def radial_sigma_ut(self, raw_ut: NDArray) -> NDArray | None:
        """1σ of the calibrated magnitude this fit gives each raw reading (µT); None when the fit
        carries no covariance to say it."""
        return None if self.radial is None else self.radial.sigma_ut(raw_ut)

    def apply(self, m_ut: NDArray) -> NDArray:
        """Calibrate raw samples (µT) with this fit (drift-free end state)."""
        return (np.asarray(m_ut, float) - self.hard_iron_ut) @ self.soft_iron.T

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able dictionary (the `magline fit --json` document)."""
        res = self.residuals_ut
        return {
            "model": self.model,
            "hard_iron_ut": [float(v) for v in self.hard_iron_ut],
            "hard_iron_sigma_ut": [float(v) for v in self.hard_iron_sigma_ut],
            "soft_iron": [[float(v) for v in row] for row in self.soft_iron],
            "soft_iron_sigma": [[float(v) for v in row] for row in self.soft_iron_sigma],
            "field_ut": float(self.field_ut),
            "field_estimate_ut": float(self.field_estimate_ut),
            "field_sigma_ut": float(self.field_sigma_ut),
            "reference_field_ut": self.reference_field_ut,
            "raw_to_reference_ratio": self.raw_to_reference_ratio,
            "raw_to_reference_sigma": self.raw_to_reference_sigma,
            "axis_ratio": self.axis_ratio,
            "residual_ut": {
                "rms": self.residual_rms_ut,
                "mean": float(res.mean()),
                "std": float(res.std(ddof=1)) if len(res) > 1 else 0.0,
                "max_abs": self.residual_max_ut,
                "p95_abs": float(np.percentile(np.abs(res), 95)),
            },
            "noise_ut": float(self.noise_ut),
            "coverage": {"fraction": self.coverage, "bins": self.coverage_bins,
                         "planarity": self.planarity, "condition_number": self.condition_number,
                         "direction_sigma_deg": self.direction_sigma_deg},
            "samples": {"total": self.samples_total, "used": self.samples_used,
                        "rejected": dict(self.rejected)},
            "drift": self.drift,
            "bias_correction": self.bias_correction,
            "model_misfit": self.model_misfit,
            **({"reading_window": self.reading_window} if self.reading_window is not None else {}),
            **({"affine": self.extra} if self.model == "affine" else {}),
        }
