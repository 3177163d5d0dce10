"""Plain algebraic (linear least-squares) quadric fits.

Why keep them: they are the closed-form starting point of the geometric fit, and the textbook
9-parameter ellipsoid fit is the baseline the benchmark compares against.  They are *not* used as
the answer: on partial coverage or with outliers they are biased.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

# QR with column pivoting: rank-revealing like the SVD default (a single-axis rotation makes the
# quadric's design rank-deficient) at about half its cost on these tall, thin systems.
DRIVER = "gelsy"


class AlgebraicFitError(ValueError):
    """The quadric through the data is not an ellipsoid (or the system is singular)."""


def fit_sphere(x: NDArray) -> tuple[NDArray, float]:
    """Centre and radius of the sphere ‖x − c‖² = r² in the linear (Kåsa) sense."""
    xt = np.ascontiguousarray(x.T)
    design = np.empty((4, len(x)))  # built row-wise: its transpose is the column-major matrix LAPACK takes
    design[:3] = 2.0 * xt
    design[3] = 1.0
    from scipy import linalg  # imported on use: scipy's optimisers cost most of a CLI start that never fits

    sol, *_ = linalg.lstsq(design.T, np.einsum("ij,ij->j", xt, xt), check_finite=False, lapack_driver=DRIVER)
    centre = sol[:3]
    r2 = sol[3] + centre @ centre
    if not np.isfinite(r2) or r2 <= 0:
        raise AlgebraicFitError("sphere fit failed")
    return centre, float(np.sqrt(r2))


def fit_ellipsoid(x: NDArray) -> tuple[NDArray, NDArray]:
    """Centre ``h`` and symmetric ``S`` with ‖S(x − h)‖ ≈ 1, from the general 9-term quadric.

    Solves ``A x² + B y² + C z² + 2D xy + 2E xz + 2F yz + 2G x + 2H y + 2I z = 1``.
    """
    xt = np.ascontiguousarray(x.T)
    design = np.empty((9, len(x)))  # row-wise, as in fit_sphere
    design[:3] = xt * xt
    design[3] = 2 * xt[0] * xt[1]
    design[4] = 2 * xt[0] * xt[2]
    design[5] = 2 * xt[1] * xt[2]
    design[6:] = 2 * xt
    from scipy import linalg  # imported on use: scipy's optimisers cost most of a CLI start that never fits

    sol, *_ = linalg.lstsq(design.T, np.ones(len(x)), check_finite=False, lapack_driver=DRIVER)
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
