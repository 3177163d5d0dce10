"""The full affine calibration, possible when the applied field is known (a Helmholtz coil).

With Earth-field tumbling only the field's *magnitude* is known, so only the symmetric part of
the calibration matrix is determined.  When a coil applies known vectors ``b`` to a unit standing
still, the sensor model ``m = A·b + h + noise`` is linear in (A, h) with the noise on the
measured side, so ordinary least squares is the maximum-likelihood estimate: the offset and a full,
non-symmetric matrix including the sensor's misalignment to the coil (fixture) frame.

``M = A⁻¹`` is the full calibration (``b = M·(m − h)``); its polar decomposition ``M = R·P``
splits it into what autopilots can hold — the symmetric ``P`` (magline's ``soft_iron``) — and a
rotation ``R`` reported as the misalignment angle.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from magline.core.fit.result import FitRefused, FitResult

MIN_STEPS = 7  # distinct applied vectors; 12 unknowns need several well spread ones


def fit_affine(mag_ut: NDArray, applied_ut: NDArray, field_ut: float | None = None) -> FitResult:
    """Least-squares ``m = A·b + h``; returns the symmetric part as ``soft_iron`` and, in ``extra``,
    the full matrix, the rotation and the misalignment angle (degrees)."""
    m = np.asarray(mag_ut, float)
    b = np.asarray(applied_ut, float)
    if m.shape != b.shape or m.ndim != 2 or m.shape[1] != 3:
        raise ValueError("mag_ut and applied_ut must both be N×3")
    steps = np.unique(np.round(b, 3), axis=0)
    spread = np.linalg.svd(steps - steps.mean(axis=0), compute_uv=False) if len(steps) > 1 else np.zeros(3)
    if len(steps) < MIN_STEPS or spread[-1] < 1e-6 * max(spread[0], 1e-12):
        raise FitRefused("degenerate_schedule",
                         f"only {len(steps)} distinct applied field vectors, not spanning three axes",
                         "check the coil schedule: it needs well spread directions on all three axes")
    x = np.column_stack([b, np.ones(len(b))])
    theta, *_ = np.linalg.lstsq(x, m, rcond=None)
    a, h = theta[:3].T, theta[3]
    predicted = x @ theta
    dof = max(3 * (len(m) - 4), 1)
    sigma2 = float(np.sum((m - predicted) ** 2) / dof)
    xtx_inv = np.linalg.inv(x.T @ x)
    h_sigma = np.sqrt(sigma2 * xtx_inv[3, 3]) * np.ones(3)
    full = np.linalg.inv(a)
    rotation, sym = _rotation_then_symmetric(full)
    if np.linalg.det(rotation) < 0:
        raise FitRefused("reflected_axes", "the fitted matrix reflects an axis (a sensor axis is wired reversed)",
                         "check the sensor's orientation setting / wiring before calibrating")
    from scipy.spatial.transform import (
        Rotation,  # imported on use: scipy's optimisers cost most of a CLI start that never fits
    )

    rotvec = Rotation.from_matrix(rotation).as_rotvec(degrees=True)
    magnitudes = np.linalg.norm(b, axis=1)
    live = magnitudes > 1e-9
    field = float(field_ut) if field_ut is not None else float(magnitudes[live].mean())
    calibrated = (m - h) @ sym.T
    residuals = np.linalg.norm(calibrated, axis=1) - magnitudes
    full_sigma, soft_sigma = _matrix_sigmas(a, sigma2 * xtx_inv[:3, :3])
    return FitResult(
        model="affine", hard_iron_ut=h, soft_iron=sym, field_ut=field,
        field_estimate_ut=float(np.linalg.norm(calibrated[live], axis=1).mean()) if live.any() else field,
        field_sigma_ut=float(np.sqrt(sigma2 / max(live.sum(), 1))), reference_field_ut=field_ut,
        raw_to_reference_ratio=float(np.mean(np.linalg.norm(m[live] - h, axis=1) / magnitudes[live]))
        if live.any() and field_ut is not None else None,
        raw_to_reference_sigma=None, hard_iron_sigma_ut=h_sigma, soft_iron_sigma=soft_sigma,
        residuals_ut=residuals, used=np.ones(len(m), bool), samples_total=len(m), rejected={},
        coverage=1.0, coverage_bins=len(steps), planarity=float(spread[-1] / spread[0]),
        condition_number=float(np.linalg.cond(x.T @ x)),
        direction_sigma_deg=calibrated_direction_sigma_deg(full, sigma2, xtx_inv, steps),
        noise_ut=float(np.sqrt(sigma2)),
        extra={"method": "affine (known applied field)", "full_matrix": full.tolist(),
               "full_matrix_sigma": full_sigma.tolist(),
               "rotation": rotation.tolist(), "misalignment_deg": float(np.linalg.norm(rotvec)),
               "misalignment_rotvec_deg": rotvec.tolist(), "steps": len(steps)},
    )


def calibrated_direction_sigma_deg(full: NDArray, sigma2: float, xtx_inv: NDArray, steps: NDArray) -> float:
    """Largest 1σ error (degrees) of the calibrated field direction over the applied vectors, as the
    ellipsoid fit's ``direction_sigma_deg`` is over the orientations seen: what the calibration's
    own uncertainty, not one reading's noise, leaves in a heading.

    Each output axis of ``m = A·b + h`` is an independent least-squares problem on the same design
    ``x = [b, 1]``, so at an applied ``b`` every axis of ``A·b + h`` has variance ``σ²·xᵀ(XᵀX)⁻¹x``;
    ``M = A⁻¹`` carries that error into the calibrated field, and only its part across ``b`` turns
    the direction."""
    worst = 0.0
    for b in steps:
        size = float(np.linalg.norm(b))
        if size < 1e-9:
            continue
        x = np.append(b, 1.0)
        variance = sigma2 * float(x @ xtx_inv @ x)
        u = b / size
        across = (np.eye(3) - np.outer(u, u)) @ full
        worst = max(worst, variance * float(np.sum(across * across)) / size**2)
    return float(np.degrees(np.sqrt(worst)))


def _matrix_sigmas(a: NDArray, column_cov: NDArray, step: float = 1e-6) -> tuple[NDArray, NDArray]:
    """1σ of each element of the full calibration ``M = A⁻¹`` and of its symmetric part ``P``, carried from
    the fitted ``A`` to first order.  Each row of ``A`` is its own least-squares problem on one design, so
    ``cov(A_ij, A_kl) = δ_ik · column_cov[j, l]`` (``σ²·(XᵀX)⁻¹`` over the applied axes).  Why not scale one
    σ by each element's size: the off-diagonal elements near zero then read 25–45 times too certain (a Monte
    Carlo of this fit), and a quality engineer reading the record would trust a cross-axis term that much too
    far.  The derivatives of the inverse and of the polar decomposition are taken by central differences."""
    cov = np.kron(np.eye(3), column_cov)  # A flattened row by row
    jac_full, jac_sym = np.empty((9, 9)), np.empty((9, 9))
    for k in range(9):
        delta = np.zeros(9)
        delta[k] = step
        up, down = a + delta.reshape(3, 3), a - delta.reshape(3, 3)
        full_up, full_down = np.linalg.inv(up), np.linalg.inv(down)
        jac_full[:, k] = (full_up - full_down).ravel() / (2 * step)
        sym_up, sym_down = _rotation_then_symmetric(full_up)[1], _rotation_then_symmetric(full_down)[1]
        jac_sym[:, k] = (sym_up - sym_down).ravel() / (2 * step)
    full_sigma = np.sqrt(np.einsum("ik,kl,il->i", jac_full, cov, jac_full)).reshape(3, 3)
    sym_sigma = np.sqrt(np.einsum("ik,kl,il->i", jac_sym, cov, jac_sym)).reshape(3, 3)
    return full_sigma, sym_sigma


def _rotation_then_symmetric(full: NDArray) -> tuple[NDArray, NDArray]:
    """``full = R·P`` with R a rotation and P symmetric positive definite."""
    from scipy.linalg import polar  # imported on use: scipy's optimisers cost most of a CLI start that never fits

    u, p = polar(full, side="right")  # full = u @ p
    return u, p
