"""The natural cubic smoothing spline of a stream's readings, made in a handful of array operations.

What it is: the function ``f`` that minimises ``Σ |yᵢ − f(xᵢ)|² + λ ∫ f″(u)² du`` over every twice
differentiable function — a natural cubic spline with a knot at each reading — found by Reinsch's
algorithm (Green & Silverman, *Nonparametric Regression and Generalized Linear Models*, 1994, §2.3): the
second derivatives at the inner knots solve one symmetric five-diagonal system, and the fitted values
follow from them.  It is the same function as SciPy's ``make_smoothing_spline(x, y, lam=λ)`` (a test holds
the two to 1e-9 of the readings' scale).

Why not SciPy's: it builds its penalty with a Python loop over the readings, and the mounting check makes
three such splines over the accelerometer's stream each time it looks (the whole stream and each half),
which a tumble does several times while it runs: for 6,000 readings SciPy's took 88 ms, this takes 3 ms,
and a whole mounting estimate over them 39 ms instead of 175 (``benchmarks/store_and_spline.py``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True)
class SmoothingSpline:
    """The spline through knots ``x``: its values ``g`` and second derivatives ``gamma`` there (both
    ``(n, columns)``; ``gamma`` zero at the ends, as a natural spline's)."""

    x: NDArray
    g: NDArray
    gamma: NDArray
    _pieces: Any = field(default=None, repr=False, compare=False)  # SciPy's PPoly of it, made on first use

    @classmethod
    def fit(cls, x: NDArray, y: NDArray, lam: float) -> SmoothingSpline:
        """The smoothing spline of readings ``y`` (rows, any number of columns) at strictly increasing
        ``x`` with smoothing ``lam`` (≥ 0); at least three readings."""
        x = np.asarray(x, float)
        y = np.asarray(y, float)
        flat = y.ndim == 1
        y = y.reshape(len(x), -1)
        n = len(x)
        if n < 3 or np.any(np.diff(x) <= 0):
            raise ValueError("a smoothing spline needs at least three readings at increasing instants")
        h = np.diff(x)
        inv = 1.0 / h
        # Q (n × n−2): column j (inner knot j+1) holds 1/h_j, −1/h_j − 1/h_{j+1}, 1/h_{j+1} at rows j, j+1, j+2
        q_lo, q_mid, q_hi = inv[:-1], -inv[:-1] - inv[1:], inv[1:]
        # Qᵀy, one row per inner knot
        qty = q_lo[:, None] * y[:-2] + q_mid[:, None] * y[1:-1] + q_hi[:, None] * y[2:]
        # R + λ·QᵀQ: symmetric, five diagonals; stored as its upper bands for solveh_banded
        m = n - 2
        diag0 = (h[:-1] + h[1:]) / 3.0 + lam * (q_lo**2 + q_mid**2 + q_hi**2)
        diag1 = h[1:-1] / 6.0 + lam * (q_mid[:-1] * q_lo[1:] + q_hi[:-1] * q_mid[1:])
        diag2 = lam * (q_hi[:-2] * q_lo[2:])
        bands = np.zeros((3, m))
        bands[0, 2:] = diag2
        bands[1, 1:] = diag1
        bands[2, :] = diag0
        from scipy.linalg import solveh_banded  # on use: scipy costs every command start

        inner = solveh_banded(bands, qty, check_finite=False)
        gamma = np.zeros_like(y)
        gamma[1:-1] = inner
        # g = y − λ·Q·γ (inner γ only)
        q_gamma = np.zeros_like(y)
        q_gamma[:-2] += q_lo[:, None] * inner
        q_gamma[1:-1] += q_mid[:, None] * inner
        q_gamma[2:] += q_hi[:, None] * inner
        g = y - lam * q_gamma
        if flat:
            return cls(x, g[:, 0], gamma[:, 0])
        return cls(x, g, gamma)

    def __call__(self, when: NDArray) -> NDArray:
        """The spline at ``when`` (inside the knots; beyond them, its end pieces carried on)."""
        if self._pieces is None:
            object.__setattr__(self, "_pieces", self._piecewise())
        return self._pieces(np.asarray(when, float))

    def _piecewise(self) -> Any:
        """The spline as SciPy's piecewise polynomial (evaluated in compiled code): on the knot interval
        from xᵢ, ``gᵢ + bᵢ·s + γᵢ/2·s² + (γᵢ₊₁ − γᵢ)/(6hᵢ)·s³`` with ``bᵢ = (gᵢ₊₁ − gᵢ)/hᵢ − hᵢ(2γᵢ + γᵢ₊₁)/6``."""
        from scipy.interpolate import PPoly

        h = np.diff(self.x)
        g, gamma = self.g, self.gamma
        if g.ndim == 2:
            h = h[:, None]
        slope = (g[1:] - g[:-1]) / h - h * (2.0 * gamma[:-1] + gamma[1:]) / 6.0
        coefficients = np.stack([(gamma[1:] - gamma[:-1]) / (6.0 * h), gamma[:-1] / 2.0, slope, g[:-1]])
        return PPoly(coefficients, self.x, extrapolate=True)
