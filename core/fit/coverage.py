"""Direction coverage: the one definition used everywhere (live bar, phase log, the ``coverage``
measurement, ``magline fit``).

Why Fibonacci bins: they split the sphere into cells of (nearly) equal area for any count, so
"fraction of bins hit" means "fraction of the sphere seen" whatever bin count a station chooses.

The definition, :func:`coverage_of`, is a function of the samples *in the order they arrived*:
every :data:`CHECK_EVERY` samples (and at the end) the centre of the readings is estimated by an
algebraic sphere fit of all samples so far; the samples are binned by their direction about that
centre (all of them again when the centre moved by more than :data:`RECENTRE_TOL` of the radius
since the last binning, else only the new ones), and the coverage is the highest fraction reached
at any checkpoint.  So the figure never decreases while an attempt's samples arrive, and the live
bar's last value, the attempt's figure and the fit's measurement are the same number: no
calibration is needed to compute it (hard iron dominates the raw offset; soft iron only tilts
directions a little).
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

CHECK_EVERY = 25  # samples between checkpoints of the centre estimate
RECENTRE_TOL = 0.01  # re-bin every sample when the centre moved by more than this share of the radius
# A "sphere" smaller than this is no field's: readings of a unit held still are a cluster whose noise,
# binned about its own centre, lit the whole sphere before the unit had turned at all (a turntable's
# unit waiting for its first tilt).  Earth's field is 22–67 µT; a coil's is of that size too.
MIN_RADIUS_UT = 10.0


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
    """Fraction of the ``n_bins`` bins that hold at least one direction (about a known centre)."""
    if len(directions) == 0:
        return 0.0
    return float(np.unique(bin_index(directions, n_bins)).size / n_bins)


def coverage_of(samples_ut: NDArray, n_bins: int, *, final: bool = True) -> float:
    """The coverage of raw samples in arrival order (see the module docstring).

    ``final=False`` evaluates only the checkpoints reached so far, not the end: what the live bar
    shows while more samples are coming (the end of the attempt adds the last evaluation).
    Between two re-centrings the hit bins only grow, so each run of checkpoints with one centre
    is binned once, at its last checkpoint: the same figure as binning at every checkpoint.
    """
    return covered_bins(samples_ut, n_bins, final=final).size / n_bins


def covered_bins(samples_ut: NDArray, n_bins: int, *, final: bool = True) -> NDArray:
    """The direction bins behind :func:`coverage_of`'s figure (sorted indices into
    :func:`fibonacci_sphere`): what an operator screen lights up."""
    x = np.atleast_2d(np.asarray(samples_ut, float)) if len(samples_ut) else np.empty((0, 3))
    n = len(x)
    checkpoints = list(range(CHECK_EVERY, n + 1, CHECK_EVERY))
    if final and n and (not checkpoints or checkpoints[-1] != n):
        checkpoints.append(n)
    if not checkpoints:
        return np.empty(0, dtype=int)
    centres, radii = _prefix_sphere_centres(x, np.array(checkpoints))
    best, centre, radius, end = np.empty(0, dtype=int), None, 0.0, 0
    for k, c, r in zip(checkpoints, centres.tolist(), radii.tolist(), strict=True):
        if centre is None or math.dist(c, centre) > RECENTRE_TOL * r:
            if centre is not None:
                best = _more(best, _binned(x[:end], centre, radius, n_bins))
            centre, radius = c, r
        end = k
    return _more(best, _binned(x[:end], centre, radius, n_bins))


def _binned(x: NDArray, centre, radius: float, n_bins: int) -> NDArray:
    """The bins of ``x``'s directions about ``centre``; none about a "sphere" too small to be a field's."""
    if radius < MIN_RADIUS_UT:
        return np.empty(0, dtype=int)
    return np.unique(bin_index(x - np.asarray(centre), n_bins))


def _more(a: NDArray, b: NDArray) -> NDArray:
    return b if b.size > a.size else a


def _prefix_sphere_centres(x: NDArray, ends: NDArray) -> tuple[NDArray, NDArray]:
    """Centre and radius of the algebraic sphere fit of ``x[:k]`` for every ``k`` in ``ends``.

    ``|x|² = 2c·x + d`` solved by least squares for each prefix at once from cumulative normal
    equations; a prefix that cannot determine a sphere (too few or coplanar points) takes the
    mean as its centre.
    """
    shift = x[: ends[0]].mean(axis=0)  # conditioning only: the fit is shift-invariant
    y = x - shift
    rows = np.column_stack([2.0 * y, np.ones(len(y))])
    rhs = np.einsum("ij,ij->i", y, y)
    gram = np.cumsum(rows[:, :, None] * rows[:, None, :], axis=0)[ends - 1]
    moment = np.cumsum(rows * rhs[:, None], axis=0)[ends - 1]
    diag = np.prod(np.diagonal(gram, axis1=1, axis2=2), axis=1)
    solvable = (ends >= 4) & (np.abs(np.linalg.det(gram)) > 1e-12 * np.maximum(diag, 1e-300))
    centres = np.cumsum(y, axis=0)[ends - 1] / ends[:, None]  # the mean, where no sphere is determined
    r2 = np.zeros(len(ends))
    if solvable.any():
        sol = np.linalg.solve(gram[solvable], moment[solvable][..., None])[..., 0]
        centres[solvable] = sol[:, :3]
        r2[solvable] = sol[:, 3] + np.einsum("ij,ij->i", sol[:, :3], sol[:, :3])
    for i in np.flatnonzero(r2 <= 0):  # degenerate prefixes: the mean distance from the centre
        r2[i] = float(np.mean(np.sum((y[: ends[i]] - centres[i]) ** 2, axis=1)))
    return centres + shift, np.sqrt(np.maximum(r2, 1e-12))


def sphere_centre(samples_ut: NDArray) -> NDArray:
    """The algebraic sphere's centre of all the readings (their mean where none is determined): the
    centre coverage bins are taken about."""
    x = np.atleast_2d(np.asarray(samples_ut, float))
    return _prefix_sphere_centres(x, np.array([len(x)]))[0][0]


class CoverageTracker:
    """Live coverage while samples arrive: :func:`coverage_of` at each checkpoint reached.

    The value only changes when a checkpoint is crossed, never decreases, and the attempt's own
    figure (``coverage_of`` of all its samples) is at least the last value shown.
    """

    def __init__(self, n_bins: int) -> None:
        self.n_bins = n_bins
        self._samples: list[NDArray] = []
        self._count = 0
        self.fraction = 0.0
        self.bins: NDArray = np.empty(0, dtype=int)  # the bins behind the fraction

    def add(self, samples_ut: NDArray) -> float:
        samples_ut = np.atleast_2d(np.asarray(samples_ut, float))
        before = self._count // CHECK_EVERY
        self._samples.append(samples_ut)
        self._count += len(samples_ut)
        if self._count // CHECK_EVERY > before:
            bins = covered_bins(np.vstack(self._samples), self.n_bins, final=False)
            if bins.size / self.n_bins >= self.fraction:
                self.fraction, self.bins = bins.size / self.n_bins, bins
        return self.fraction
