"""Parameterisation of the calibration model ``m_cal = S·(m_raw − h − D·τ)`` in normalised units.

Why a module of its own: the geometric fit, the Cramér–Rao bound in the benchmark and the
uncertainty propagation all need the same residual and the same Jacobian; keeping them here means
the bound is computed for exactly the estimator that is run.

Normalised units: raw samples are shifted and scaled (``x = (m − centre)/scale``) so that the target
radius is 1 and every parameter is of order one, which keeps the least-squares problem well scaled.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Literal

import numpy as np
from numpy.typing import NDArray

SoftIronModel = Literal["full", "diagonal", "sphere"]

N_SOFT: dict[str, int] = {"full": 6, "diagonal": 3, "sphere": 1}
# Index pairs of the six independent entries of a symmetric 3×3 matrix, in parameter order.
FULL_INDEX = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))
# For each entry of the 3×3 matrix (row-major), which of the six parameters it holds.
_FULL_ENTRY = np.array([0, 3, 4, 3, 1, 5, 4, 5, 2])


@dataclass(frozen=True)
class Layout:
    """Where each group of parameters sits in the parameter vector."""

    model: SoftIronModel
    drift: bool

    @cached_property
    def n_soft(self) -> int:
        return N_SOFT[self.model]

    @cached_property
    def size(self) -> int:
        return 3 + self.n_soft + (3 if self.drift else 0)

    @cached_property
    def soft_slice(self) -> slice:
        return slice(3, 3 + self.n_soft)

    @cached_property
    def drift_slice(self) -> slice:
        return slice(3 + self.n_soft, 3 + self.n_soft + 3)


def soft_matrix(model: SoftIronModel, s: NDArray[np.float64]) -> NDArray[np.float64]:
    """Build the symmetric soft-iron matrix from its free parameters."""
    if model == "sphere":
        return np.eye(3) * s[0]
    if model == "diagonal":
        return np.diag(s)
    return np.asarray(s)[_FULL_ENTRY].reshape(3, 3)


def soft_params(model: SoftIronModel, m: NDArray[np.float64]) -> NDArray[np.float64]:
    """Inverse of :func:`soft_matrix` (projecting onto the model's form)."""
    if model == "sphere":
        return np.array([np.cbrt(abs(np.linalg.det(m)))])
    if model == "diagonal":
        return np.diag(m).copy()
    sym = 0.5 * (m + m.T)
    return np.array([sym[i, j] for i, j in FULL_INDEX])


def pack(layout: Layout, h: NDArray, s_matrix: NDArray, drift: NDArray | None = None) -> NDArray:
    parts = [np.asarray(h, float), soft_params(layout.model, s_matrix)]
    if layout.drift:
        parts.append(np.zeros(3) if drift is None else np.asarray(drift, float))
    return np.concatenate(parts)


def unpack(layout: Layout, p: NDArray) -> tuple[NDArray, NDArray, NDArray]:
    h = p[:3]
    s = soft_matrix(layout.model, p[layout.soft_slice])
    d = p[layout.drift_slice] if layout.drift else np.zeros(3)
    return h, s, d


# The functions below work with the samples along the last axis (3 × n): numpy then runs along
# long contiguous rows instead of rows of three, several times faster on a 600-sample fit.

def _centred(layout: Layout, p: NDArray, x: NDArray, tau: NDArray | None) -> tuple[NDArray, NDArray]:
    """(S, d): the soft-iron matrix and the centred samples d = x − h − drift·τ (3 × n)."""
    h, s, drift = unpack(layout, p)
    d = x.T - h[:, None]
    if layout.drift and tau is not None:
        d = d - np.outer(drift, tau)
    return s, d


def radial(layout: Layout, p: NDArray, x: NDArray, tau: NDArray | None) -> NDArray:
    """ρ = |S·(x − h − drift·τ)| per sample: the calibrated radius (1 on the model)."""
    s, d = _centred(layout, p, x, tau)
    v = s @ d
    return np.sqrt(np.einsum("ij,ij->j", v, v))


def radial_gradient(layout: Layout, p: NDArray, x: NDArray, tau: NDArray | None) -> tuple[NDArray, NDArray]:
    """(ρ, ∇ρ) per sample; ∇ρ = ∂ρ/∂x = S·S·d/ρ is returned as a 3 × n array."""
    s, d = _centred(layout, p, x, tau)
    v = s @ d
    rho = np.sqrt(np.einsum("ij,ij->j", v, v))
    return rho, (s @ v) / rho


def gradient_norm(layout: Layout, p: NDArray, x: NDArray, tau: NDArray | None) -> NDArray:
    """|∇ρ| in raw units per sample: converts a radial misfit into a geometric (raw-space) distance.

    Dividing by it turns the algebraic radial residual into the Sampson approximation of the
    orthogonal distance to the ellipsoid, which is what isotropic raw-sensor noise makes Gaussian.
    """
    return radial_with_gradient_norm(layout, p, x, tau)[1]


def radial_with_gradient_norm(layout: Layout, p: NDArray, x: NDArray, tau: NDArray | None):
    """(ρ, |∇ρ|) per sample in one pass: what a geometric residual (ρ − 1)/|∇ρ| needs."""
    rho, g = radial_gradient(layout, p, x, tau)
    return rho, np.sqrt(np.einsum("ij,ij->j", g, g))


_FULL_I = np.array([i for i, _ in FULL_INDEX])
_FULL_J = np.array([j for _, j in FULL_INDEX])


def radial_jacobian(layout: Layout, p: NDArray, x: NDArray, tau: NDArray | None) -> tuple[NDArray, NDArray]:
    """ρ and ∂ρ/∂p for every sample (analytic; S symmetric).

    Computed with the samples along the last axis (3 × n, parameters × n), where numpy works on
    long contiguous rows; the (n, parameters) Jacobian returned is a transposed view of that.
    """
    s, d = _centred(layout, p, x, tau)
    v = s @ d
    rho = np.sqrt(np.einsum("ij,ij->j", v, v))
    inv_rho = 1.0 / rho
    g = (s @ v) * inv_rho  # ∂ρ/∂x
    jac = np.empty((layout.size, x.shape[0]))
    jac[:3] = -g
    soft = layout.soft_slice
    if layout.model == "sphere":
        jac[soft] = rho / p[3]
    elif layout.model == "diagonal":
        jac[soft] = v * d * inv_rho
    else:
        # ∂ρ/∂S_ij = (v_i·d_j + v_j·d_i)/ρ off the diagonal, v_i·d_i/ρ on it
        both = v[_FULL_I] * d[_FULL_J]
        both[3:] += v[_FULL_J[3:]] * d[_FULL_I[3:]]
        jac[soft] = both * inv_rho
    if layout.drift:
        jac[layout.drift_slice] = -g * (tau if tau is not None else 0.0)
    return rho, jac.T


def _soft_basis(model: SoftIronModel) -> NDArray[np.float64]:
    """∂S/∂s_k for each soft-iron parameter: an (n_soft, 3, 3) stack of constant matrices."""
    if model == "sphere":
        return np.eye(3)[None]
    if model == "diagonal":
        return np.stack([np.diag(e) for e in np.eye(3)])
    basis = np.zeros((6, 3, 3))
    for k, (i, j) in enumerate(FULL_INDEX):
        basis[k, i, j] = basis[k, j, i] = 1.0
    return basis


_SOFT_BASIS = {model: _soft_basis(model) for model in N_SOFT}


def direction_jacobian(layout: Layout, p: NDArray, x: NDArray) -> tuple[NDArray, NDArray]:
    """Calibrated unit directions u = S·(x − h)/|S·(x − h)| and ∂u/∂(h, s) for every sample.

    Returns u (3, n) and the Jacobian (3 + n_soft, 3, n): ``[k, :, i]`` is ∂u_i/∂p_k (samples
    along the last axis, where numpy works on long contiguous rows).  Drift terms have no row:
    the direction that matters is the end state (τ = 0), which they do not move.  Why analytic:
    propagating the covariance into heading error is done on every fit, and this is one pass over
    the samples where finite differences take one per parameter.
    """
    h, s, _ = unpack(layout, p)
    d = x.T - h[:, None]
    c = s @ d
    norm = np.sqrt(np.einsum("ij,ij->j", c, c))
    u = c / norm
    dc = np.empty((3 + layout.n_soft, 3, len(x)))
    dc[:3] = -s[:, :, None]  # ∂c/∂h_k = −S·e_k, the k-th row of the symmetric S
    dc[3:] = (_SOFT_BASIS[layout.model].reshape(-1, 3) @ d).reshape(layout.n_soft, 3, -1)  # E_k·d
    # a unit vector moves only across itself: (I − u·uᵀ)·∂c / |c|
    along = np.einsum("kan,an->kn", dc, u)
    return u, (dc - along[:, None, :] * u) / norm


def log_radius_and_gradient(layout: Layout, p: NDArray) -> tuple[float, NDArray]:
    """``(−⅓·log det S, its gradient ∂/∂p)``: the log of the raw field radius implied by S (target
    radius 1), NaN where det S ≤ 0, and how it moves with the parameters.

    Why one function in closed form: the reference field's prior row needs both at every evaluation of
    the fit's objective (thousands per fit, with the bias bootstrap's refits), and LAPACK's determinant
    and inverse of a 3 × 3 matrix, called separately, cost more in their call than in their arithmetic.
    """
    grad = np.zeros(layout.size)
    if layout.model == "sphere":
        grad[3] = -1.0 / p[3]
        det = p[3] ** 3
        return (float(-np.log(det) / 3.0) if det > 0 else float("nan")), grad
    if layout.model == "diagonal":
        a, b, c = (float(v) for v in p[3:6])
        det = a * b * c
        grad[3:6] = (-1.0 / (3.0 * a), -1.0 / (3.0 * b), -1.0 / (3.0 * c))
        return (float(-np.log(det) / 3.0) if det > 0 else float("nan")), grad
    a, b, c, d, e, f = p[3:9].tolist()  # S = [[a, d, e], [d, b, f], [e, f, c]]
    # the cofactors of a symmetric 3 × 3: S⁻¹ = cofactors / det S
    ca, cb, cc = b * c - f * f, a * c - e * e, a * b - d * d
    cd, ce, cf = e * f - d * c, d * f - b * e, d * e - a * f
    det = a * ca + d * cd + e * ce
    # ∂(−⅓ log det S)/∂S_ij = −⅓ (S⁻¹)_ij; an off-diagonal parameter holds two entries
    scale = -3.0 * det
    grad[3:9] = (ca / scale, cb / scale, cc / scale, 2.0 * cd / scale, 2.0 * ce / scale, 2.0 * cf / scale)
    return (float(-np.log(det) / 3.0) if det > 0 else float("nan")), grad


def log_gain_gradient(layout: Layout, p: NDArray) -> NDArray:
    """∂/∂p of −⅓·log det S: the log of the raw field radius implied by S (target radius 1)."""
    return log_radius_and_gradient(layout, p)[1]


def log_raw_radius(layout: Layout, p: NDArray) -> float:
    return log_radius_and_gradient(layout, p)[0]
