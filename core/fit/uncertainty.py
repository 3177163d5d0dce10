"""What the parameter covariance means where the calibration is used: soft-iron 1σ, the
condition of the problem, and the heading uncertainty over the orientations seen.

Why a module of its own: these turn the fit's covariance into the figures the station's limits
and the operator's retry prompt are judged on, and nothing in them depends on how the fit was
found.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from magline.core.fit import model as mdl


def condition_number(gram: NDArray) -> float:
    """Condition number of the column-normalised Jacobian, from its Gram matrix JᵀJ (at most
    12×12, where an SVD of the tall Jacobian would cost as much as a 100 000-sample fit); NaN when
    singular.  The squared condition it works with is exact enough for a figure whose use is
    "finite, and how large"."""
    norms = np.sqrt(np.diag(gram))
    if not np.all(np.isfinite(gram)) or np.any(norms <= 0):
        return float("nan")
    eig = np.linalg.eigvalsh(gram / np.outer(norms, norms))
    return float(np.sqrt(eig[-1] / eig[0])) if eig[0] > 0 else float("nan")


def direction_sigma_deg(layout: mdl.Layout, p: NDArray, cov: NDArray, x: NDArray) -> float:
    """Largest 1σ error (degrees) of the calibrated field direction over the samples seen.

    First-order propagation of the parameter covariance (drift terms excluded: end state):
    the variance of each sample's direction is |∂u/∂p · L|² with Σ = L·Lᵀ.
    """
    core = 3 + layout.n_soft
    w, vecs = np.linalg.eigh(cov[:core, :core])
    root = vecs * np.sqrt(np.clip(w, 0, None))  # Σ = root·rootᵀ, also when Σ is only semi-definite
    _, du = mdl.direction_jacobian(layout, p, x)
    spread = root.T @ du.reshape(core, -1)  # (core, 3·n): one product for all samples
    return float(np.degrees(np.sqrt(np.square(spread).sum(axis=0).reshape(3, -1).sum(axis=0).max())))


def soft_sigma(layout: mdl.Layout, cov: NDArray, factor: float) -> NDArray:
    """1σ of each soft-iron entry as a 3×3 matrix, the parameters' σ scaled by ``factor`` (from
    normalised units to the reported matrix)."""
    var = np.clip(np.diag(cov)[layout.soft_slice], 0, None)
    sig = np.sqrt(var) * factor
    if layout.model == "sphere":
        return np.eye(3) * sig[0]
    if layout.model == "diagonal":
        return np.diag(sig)
    return mdl.soft_matrix("full", sig)
