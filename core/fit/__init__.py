"""Calibration math: the hard/soft-iron fit, coverage, and the raw-sample CSV format.

The sequencer's default fit hook calls :func:`fit_calibration`; a plugin can replace it through
the ``magline_fit`` hook.
"""

from magline.core.fit.coverage import CoverageTracker, coverage_fraction, coverage_of, fibonacci_sphere
from magline.core.fit.geometric import fit_calibration
from magline.core.fit.result import FitOptions, FitRefused, FitResult

__all__ = [
    "CoverageTracker",
    "FitOptions",
    "FitRefused",
    "FitResult",
    "coverage_fraction",
    "coverage_of",
    "fibonacci_sphere",
    "fit_calibration",
]
