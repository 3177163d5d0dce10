"""Calibration math: the hard/soft-iron fit, coverage, and the raw-sample CSV format.

The sequencer's default fit hook calls :func:`fit_calibration`; a plugin can replace it through
the ``magline_fit`` hook.

Its names are imported on first use (:mod:`magline.core.lazy`).
"""

from __future__ import annotations

from magline.core.lazy import lazy_names

__all__, __getattr__, __dir__ = lazy_names(__name__, {
    "magline.core.fit.coverage": ("CoverageTracker", "coverage_fraction", "coverage_of", "fibonacci_sphere"),
    "magline.core.fit.geometric": ("fit_calibration",),
    "magline.core.fit.result": ("FitOptions", "FitRefused", "FitResult"),
})
