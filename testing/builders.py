"""Builders for the objects a plugin's unit tests need: a fit result and a run record.

Why: ``FitResult`` carries some twenty figures the fit computes; a test of a parameter conversion
needs only ``h``, ``S`` and the field, and must not hand-make the rest.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from magline.core import __version__
from magline.core.fit import FitResult
from magline.core.record import Outcome, RunRecord


def make_fit(hard_iron_ut: ArrayLike = (0.0, 0.0, 0.0), soft_iron: ArrayLike | None = None, field_ut: float = 48.0,
             model: str = "full", **overrides: Any) -> FitResult:
    """A fit whose calibration is ``S·(m − h)`` on a sphere of ``field_ut`` (µT), every quality figure
    perfect (no residual, full coverage); ``overrides`` set any other field."""
    h = np.asarray(hard_iron_ut, float).reshape(3)
    s = np.eye(3) if soft_iron is None else np.asarray(soft_iron, float).reshape(3, 3)
    figures: dict[str, Any] = dict(
        model=model, hard_iron_ut=h, soft_iron=s, field_ut=float(field_ut), field_estimate_ut=float(field_ut),
        field_sigma_ut=0.0, reference_field_ut=float(field_ut), raw_to_reference_ratio=1.0,
        raw_to_reference_sigma=0.0, hard_iron_sigma_ut=np.zeros(3), soft_iron_sigma=np.zeros((3, 3)),
        residuals_ut=np.zeros(600), used=np.ones(600, bool), samples_total=600, rejected={}, coverage=1.0,
        coverage_bins=100, planarity=1.0, condition_number=1.0, direction_sigma_deg=0.0)
    figures.update(overrides)
    return FitResult(**figures)


def make_record(serial: str = "SN-1", part: str = "PART-1", verdict: Outcome | str = Outcome.PASS,
                **overrides: Any) -> RunRecord:
    """A finished run record (station ``test-01``, line ``TEST``); ``overrides`` set any field."""
    fields: dict[str, Any] = dict(serial=serial, part=part, station_id="test-01", line="TEST", operator="",
                                  software_version=__version__, limit_hash="", verdict=Outcome(verdict))
    fields.update(overrides)
    return RunRecord(**fields)
