"""Plain algebraic (linear least-squares) quadric fits.

Why keep them: they are the closed-form starting point of the geometric fit, and the textbook
9-parameter ellipsoid fit is the baseline the benchmark compares against.  They are *not* used as
the answer: on partial coverage or with outliers they are biased.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy import linalg


class AlgebraicFitError(ValueError):
    """The quadric through the data is not an ellipsoid (or the system is singular)."""


def fit_sphere(x: NDArray) -> tuple[NDArray, float]:
    """Centre and radius of the sphere ‖x − c‖² = r² in the linear (Kåsa) sense."""
    a = np.column_stack([2.0 * x, np.ones(len(x))])
    b = np.einsum("ij,ij->i", x, x)
    sol, *_ = linalg.lstsq(a, b, check_finite=False)
    centre = sol[:3]
    r2 = sol[3] + centre @ centre
    if not np.isfinite(r2) or r2 <= 0:
        raise AlgebraicFitError("sphere fit failed")
    return centre, float(np.sqrt(r2))


def fit_ellipsoid(x: NDArray) -> tuple[NDArray, NDArray]:
    """Centre ``h`` and symmetric ``S`` with ‖S(x − h)‖ ≈ 1, from the general 9-term quadric.

    Solves ``A x² + B y² + C z² + 2D xy + 2E xz + 2F yz + 2G x + 2H y + 2I z = 1``.
    """
    xx, yy, zz = x[:, 0], x[:, 1], x[:, 2]
    design = np.column_stack([xx * xx, yy * yy, zz * zz, 2 * xx * yy, 2 * xx * zz, 2 * yy * zz,
                              2 * xx, 2 * yy, 2 * zz])
    sol, *_ = linalg.lstsq(design, np.ones(len(x)), check_finite=False)
    a, b, c, d, e, f, g, hh, i = sol
    q = np.array([[a, d, e], [d, b, f], [e, f, c]])
    try:
        centre = -np.linalg.solve(q, np.array([g, hh, i]))
    except np.linalg.LinAlgError as exc:
        raise AlgebraicFitError("singular quadric") from exc
    scale = 1.0 + centre @ q @ centre
    if not np.isfinite(scale) or scale <= 0:
        raise AlgebraicFitError("quadric is not an ellipsoid")
    m = q / scale
    w, v = np.linalg.eigh(m)
    if np.any(w <= 0):
        raise AlgebraicFitError("quadric is not an ellipsoid")
    s = (v * np.sqrt(w)) @ v.T
    return centre, s
