"""Direction coverage on Fibonacci-sphere bins.

Why Fibonacci bins: they split the sphere into cells of (nearly) equal area for any count, so
"fraction of bins hit" means "fraction of the sphere seen" whatever bin count a station chooses.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

from magline.core.fit.algebraic import AlgebraicFitError, fit_sphere


@lru_cache(maxsize=16)
def fibonacci_sphere(n_bins: int) -> NDArray:
    """Unit vectors of ``n_bins`` near-uniform points (the bin centres)."""
    if n_bins < 4:
        raise ValueError("coverage needs at least 4 bins")
    k = np.arange(n_bins) + 0.5
    z = 1.0 - 2.0 * k / n_bins
    r = np.sqrt(1.0 - z * z)
    phi = np.pi * (1.0 + 5.0**0.5) * k
    pts = np.column_stack([r * np.cos(phi), r * np.sin(phi), z])
    pts.setflags(write=False)
    return pts


def bin_index(directions: NDArray, n_bins: int) -> NDArray:
    """Index of the nearest bin centre for each (not necessarily unit) direction."""
    centres = fibonacci_sphere(n_bins)
    out = np.empty(len(directions), dtype=int)
    for start in range(0, len(directions), 4096):  # bounded memory for 100k-sample inputs
        chunk = directions[start:start + 4096]
        out[start:start + 4096] = np.argmax(chunk @ centres.T, axis=1)
    return out


def coverage_fraction(directions: NDArray, n_bins: int) -> float:
    """Fraction of the ``n_bins`` bins that hold at least one direction."""
    if len(directions) == 0:
        return 0.0
    return float(np.unique(bin_index(directions, n_bins)).size / n_bins)


class CoverageTracker:
    """Live coverage while samples arrive, before any calibration exists.

    The centre is re-estimated with a linear sphere fit as data accumulates (hard iron dominates
    the raw offset, soft iron only tilts directions a little), so the operator sees a figure that
    converges to the post-fit coverage.
    """

    def __init__(self, n_bins: int, refit_every: int = 25) -> None:
        self.n_bins = n_bins
        self.refit_every = refit_every
        self._samples: list[NDArray] = []
        self._centre: NDArray | None = None
        self._since_fit = 0
        self.fraction = 0.0

    def add(self, samples_ut: NDArray) -> float:
        samples_ut = np.atleast_2d(np.asarray(samples_ut, float))
        self._samples.append(samples_ut)
        self._since_fit += len(samples_ut)
        if self._centre is None or self._since_fit >= self.refit_every:
            self._since_fit = 0
            data = np.vstack(self._samples)
            if len(data) >= 10:
                try:
                    self._centre, _ = fit_sphere(data)
                except AlgebraicFitError:
                    self._centre = data.mean(axis=0)
                self.fraction = coverage_fraction(data - self._centre, self.n_bins)
        return self.fraction
