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


def radial(layout: Layout, p: NDArray, x: NDArray, tau: NDArray | None):
    """Return (ρ, v, d): calibrated radius, calibrated vector and centred sample per row."""
    h, s, drift = unpack(layout, p)
    d = x - h
    if layout.drift and tau is not None:
        d = d - np.outer(tau, drift)
    v = d @ s  # s symmetric: row-wise S·d
    rho = np.sqrt(np.einsum("ij,ij->i", v, v))
    return rho, v, d


def gradient_norm(layout: Layout, p: NDArray, x: NDArray, tau: NDArray | None) -> NDArray:
    """|∇ρ| in raw units per sample: converts a radial misfit into a geometric (raw-space) distance.

    Dividing by it turns the algebraic radial residual into the Sampson approximation of the
    orthogonal distance to the ellipsoid, which is what isotropic raw-sensor noise makes Gaussian.
    """
    return radial_with_gradient_norm(layout, p, x, tau)[1]


def radial_with_gradient_norm(layout: Layout, p: NDArray, x: NDArray, tau: NDArray | None):
    """(ρ, |∇ρ|) per sample in one pass: what a geometric residual (ρ − 1)/|∇ρ| needs."""
    rho, v, _ = radial(layout, p, x, tau)
    _, s, _ = unpack(layout, p)
    g = (v @ s) / rho[:, None]
    return rho, np.sqrt(np.einsum("ij,ij->i", g, g))


def radial_jacobian(layout: Layout, p: NDArray, x: NDArray, tau: NDArray | None) -> tuple[NDArray, NDArray]:
    """ρ and ∂ρ/∂p for every sample (analytic; S symmetric)."""
    rho, v, d = radial(layout, p, x, tau)
    _, s, _ = unpack(layout, p)
    inv_rho = 1.0 / rho
    g = (v @ s) * inv_rho[:, None]  # ∂ρ/∂x
    jac = np.empty((x.shape[0], layout.size))
    jac[:, :3] = -g
    soft = jac[:, layout.soft_slice]
    if layout.model == "sphere":
        soft[:, 0] = rho / p[3]
    elif layout.model == "diagonal":
        soft[:] = v * d * inv_rho[:, None]
    else:
        for k, (i, j) in enumerate(FULL_INDEX):
            if i == j:
                soft[:, k] = v[:, i] * d[:, i] * inv_rho
            else:
                soft[:, k] = (v[:, i] * d[:, j] + v[:, j] * d[:, i]) * inv_rho
    jac[:, layout.soft_slice] = soft
    if layout.drift:
        jac[:, layout.drift_slice] = -g * (tau[:, None] if tau is not None else 0.0)
    return rho, jac


def log_gain_gradient(layout: Layout, p: NDArray) -> NDArray:
    """∂/∂p of −⅓·log det S: the log of the raw field radius implied by S (target radius 1)."""
    grad = np.zeros(layout.size)
    _, s, _ = unpack(layout, p)
    if layout.model == "sphere":
        grad[3] = -1.0 / p[3]
        return grad
    inv = np.linalg.inv(s)
    if layout.model == "diagonal":
        grad[layout.soft_slice] = -np.diag(inv) / 3.0
        return grad
    for k, (i, j) in enumerate(FULL_INDEX):
        grad[3 + k] = -(inv[i, j] if i == j else 2.0 * inv[i, j]) / 3.0
    return grad


def log_raw_radius(layout: Layout, p: NDArray) -> float:
    _, s, _ = unpack(layout, p)
    det = np.linalg.det(s)
    return float(-np.log(det) / 3.0) if det > 0 else float("nan")
