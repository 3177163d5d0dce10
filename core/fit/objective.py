"""The fit's objective: Sampson-weighted radial residuals of the samples, then the rows of the
priors a reference field brings.

Why a module of its own: the geometric fit, its Gauss–Newton polish, its covariance and the bias
bootstrap must all minimise and linearise exactly the same objective; here it is written once.
The Sampson weights |∇ρ| are frozen by the caller (per pass), which is what the bootstrap
assumes.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from magline.core.fit import model as mdl

# Samples per block when the normal equations of a large input are accumulated: the block's
# Jacobian (a few hundred kB) stays in cache, where one over 100 000 samples (7 MB, and its
# temporaries) is fetched from memory, and page-faulted in, several times over.
NORMAL_EQUATIONS_BLOCK = 8192
_IDENTITY = np.array([1.0, 1.0, 1.0, 0.0, 0.0, 0.0])  # the soft-iron parameters of S = I (full; diagonal: first 3)


def residuals_and_jacobian(layout, p, x, tau, weights, sigma, log_ref, opts, with_jacobian=True):
    """Sampson residuals (geometric distances), then any prior rows; and, if asked, their Jacobian.

    ``weights`` are the Sampson weights |∇ρ|, frozen by the caller.
    """
    if with_jacobian:
        rho, jac = mdl.radial_jacobian(layout, p, x, tau)
        jac = jac / weights[:, None]
    else:
        rho, jac = mdl.radial(layout, p, x, tau), None
    r = (rho - 1.0) / weights
    if log_ref is None:
        return r, jac
    r_prior, jac_prior = prior_rows(layout, p, sigma, log_ref, opts)
    return np.concatenate((r, r_prior)), (None if jac is None else np.concatenate((jac, jac_prior)))


def sampson_weights(jac: NDArray) -> NDArray:
    """|∇ρ| per sample, read off the radial Jacobian: its offset columns are −∂ρ/∂x."""
    return np.sqrt(np.einsum("ij,ij->i", jac[:, :3], jac[:, :3]))


def prior_rows(layout, p, sigma, log_ref, opts) -> tuple[NDArray, NDArray]:
    """Residual rows (and their Jacobian) of the priors a reference field brings, in units of σ:
    the raw field radius near the reference (1σ ``gain_sigma``) and, if set, the soft iron near
    the identity (1σ ``shape_sigma``)."""
    k = sigma / opts.gain_sigma
    log_radius, gradient = mdl.log_radius_and_gradient(layout, p)
    if not (opts.shape_sigma and layout.model != "sphere"):
        return np.array([k * (log_radius - log_ref)]), k * gradient[None, :]
    # soft iron near identity: entries of S·F_ref (raw units) with prior 1σ shape_sigma
    ks = sigma / opts.shape_sigma * np.exp(log_ref)
    n_soft = layout.n_soft
    r = np.empty(1 + n_soft)
    r[0] = k * (log_radius - log_ref)
    r[1:] = ks * (p[layout.soft_slice] - _IDENTITY[:n_soft] * np.exp(-log_ref))
    jac = np.zeros((1 + n_soft, layout.size))
    jac[0] = k * gradient
    jac[_SOFT_ROWS[n_soft]] = ks  # called thousands of times per fit: the index arrays are made once
    return r, jac


# The (row, column) of each soft-iron parameter's own entry in the prior rows' Jacobian, by their count.
_SOFT_ROWS = {n: (1 + np.arange(n), 3 + np.arange(n)) for n in (1, 3, 6)}


def normal_equations(layout, p, x, tau):
    """JᵀJ, Jᵀr and rᵀr of the Sampson residuals of the samples at ``p`` (weights frozen there),
    and the weights (|∇ρ| per sample) themselves.  Prior rows are the caller's to add.
    """
    jtj = np.zeros((layout.size, layout.size))
    jtr = np.zeros(layout.size)
    cost = 0.0
    weights = np.empty(len(x))
    for start in range(0, len(x), NORMAL_EQUATIONS_BLOCK):
        block = slice(start, start + NORMAL_EQUATIONS_BLOCK)
        rho, jac = mdl.radial_jacobian(layout, p, x[block], None if tau is None else tau[block])
        weights[block] = w = sampson_weights(jac)
        jac = jac / w[:, None]
        r = (rho - 1.0) / w
        jtj += jac.T @ jac
        jtr += jac.T @ r
        cost += float(r @ r)
    return jtj, jtr, cost, weights


def geometric_residuals(layout, p, x, tau) -> NDArray:
    """(ρ − 1)/|∇ρ| per sample with the weights at ``p``: the first-order orthogonal distance."""
    rho, grad_norm = mdl.radial_with_gradient_norm(layout, p, x, tau)
    return (rho - 1.0) / grad_norm
