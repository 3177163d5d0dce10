"""Second-order bias removal for the geometric fit (antithetic parametric bootstrap).

Why: the maximum-likelihood ellipsoid fit is unbiased only to first order.  Its O(σ²) bias is
negligible on a full tumble but, on partial coverage, it is amplified along the poorly determined
direction (offset along the axis of a hemisphere or cap) to the size of the 1σ uncertainty or
beyond.  The bias is estimated by refitting data simulated from a model: noise is drawn in
antithetic pairs (n, −n), so first-order errors cancel exactly and a handful of refits measures
the σ² term.

Why iterate: the bias is a function of the *true* parameters, and one bootstrap evaluates it at the
biased estimate.  Where the problem is strongly non-linear (a 30 % cap with a reference field) that
difference matters, so the correction is the fixed point ``p* + b(p*) = p̂`` (the parameters whose
expected estimate is what was observed), found by substitution.  A correction that does not settle
means the data do not determine the calibration, and the caller refuses.  The same noise draws
are used at every step, so the bias is a smooth function of the parameters and the substitution
converges instead of wandering with Monte Carlo noise.

Why the priors are simulated too: the reference field enters the fit as prior rows (raw field
radius near the reference, soft iron near the identity), which are observations with their own
error, just as the samples are.  Were they held fixed in the simulation, the refits would measure
the prior's pull towards its own centre as "bias" (wherever the prior, not the data, pins a
direction, as on a cap) and the correction would undo exactly the information the reference
adds.  Drawn around the simulated truth with their own σ, they leave the non-linearity bias alone
to be measured.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from magline.core.fit import model as mdl
from magline.core.fit.solver import gauss_newton, levenberg_marquardt

PAIRS = 2  # antithetic pairs for one bias estimate where the bias is small
ITERATION_PAIRS = 6  # pairs per estimate once the bias is large enough to iterate on
NEGLIGIBLE_BIAS_SIGMAS = 0.2  # one antithetic pair showing less than this (in σ) is enough
LINEAR_BIAS_SIGMAS = 0.5  # below this (in σ), one estimate is enough: the problem is locally linear
MAX_ITERATIONS = 12
# The substitution map's slope is negative on caps (the iterates overshoot and oscillate); taking
# three quarters of each step damps that, halving the iterations a 30 % cap needs.
RELAXATION = 0.75
SETTLED_SIGMAS = 0.15  # fixed-point step (in σ) below which the correction has converged
GIVE_UP_SIGMAS = 20.0  # a bias this far beyond σ has no nearby fixed point worth searching for


@dataclass(frozen=True)
class NoiseDraws:
    """One antithetic pair's noise per row: for the samples and for the prior rows (both in the
    residuals' units, σ)."""

    samples: NDArray  # (pairs, n, 3)
    priors: NDArray  # (pairs, number of prior rows)

    def __len__(self) -> int:
        return len(self.samples)

    def take(self, pairs: slice) -> NoiseDraws:
        return NoiseDraws(self.samples[pairs], self.priors[pairs])


@dataclass(frozen=True)
class BiasCorrection:
    """The estimated bias of the fit and how it was found (reported with the fit)."""

    bias: NDArray
    iterations: int  # 1: a single estimate; >1: fixed-point iterations
    settled: bool
    largest_sigmas: float  # largest |bias| / σ over the parameters
    noise: NoiseDraws | None = None  # the iteration's common random numbers (for corrected_covariance)
    # covariance of the pairs' mean refits around their mean: the second-order part of the
    # estimate's own scatter (see corrected_covariance)
    pair_cov: NDArray | None = None


def project_onto_model(layout: mdl.Layout, p: NDArray, x: NDArray, tau: NDArray | None) -> NDArray:
    """First-order projection of each sample onto the fitted ellipsoid (the 'true' points)."""
    rho, grad = mdl.radial_gradient(layout, p, x, tau)
    g2 = np.einsum("ij,ij->j", grad, grad)
    return x - (((rho - 1.0) / g2) * grad).T


def bootstrap_bias(layout: mdl.Layout, p: NDArray, x: NDArray, tau: NDArray | None, residual_fn,
                   noise: NoiseDraws) -> NDArray:
    """Mean of antithetic refits of data simulated at ``p``, minus ``p``: the bias at ``p``."""
    return pair_means(layout, p, x, tau, residual_fn, noise).mean(axis=0) - p


def pair_means(layout: mdl.Layout, p: NDArray, x: NDArray, tau: NDArray | None, residual_fn,
               noise: NoiseDraws) -> NDArray:
    """Each antithetic pair's mean refit of data simulated at ``p`` (one row per pair).

    ``residual_fn(q, x, weights, with_jacobian)`` returns (residuals, Jacobian or None) for
    parameters ``q`` on data ``x`` with frozen Sampson ``weights``: the objective the fit minimised
    (one row per sample, then its prior rows), so that the refits measure the bias of the
    estimator actually used.  ``noise`` holds one draw per antithetic pair.
    """
    truth = project_onto_model(layout, p, x, tau)
    weights = mdl.gradient_norm(layout, p, truth, tau)
    n = len(x)
    # the prior rows re-centred on the simulated truth: R(q) − R(p) is zero at p
    prior_at_truth = residual_fn(p, truth, weights, False)[0][n:]
    means = np.zeros((len(noise), len(p)))
    for pair, (sample_noise, prior_noise) in enumerate(zip(noise.samples, noise.priors, strict=True)):
        for sign in (1.0, -1.0):
            xs = truth + sign * sample_noise
            shift = sign * prior_noise - prior_at_truth

            def objective(q, jac, xs=xs, shift=shift):
                r, j = residual_fn(q, xs, weights, jac)
                r[n:] += shift
                return r, j

            refit = gauss_newton(objective, p)
            means[pair] += 0.5 * (refit if refit is not None else levenberg_marquardt(objective, p, 1e-10))
    return means


def estimate_bias(layout: mdl.Layout, p_hat: NDArray, x: NDArray, tau: NDArray | None, sigma: float,
                  residual_fn, rng: np.random.Generator, param_sigma: NDArray) -> BiasCorrection:
    """Bias of ``p_hat``: one estimate where it is small, the fixed point where it is not.

    ``param_sigma`` (per parameter) is the yardstick: "small" and "settled" are judged against it.
    """
    prior_rows = len(residual_fn(p_hat, x, np.ones(len(x)), False)[0]) - len(x)
    noise = NoiseDraws(rng.normal(scale=sigma, size=(ITERATION_PAIRS, *x.shape)),
                       rng.normal(scale=sigma, size=(ITERATION_PAIRS, prior_rows)))
    # One pair first: on a full tumble the bias is a few hundredths of σ, and a second pair
    # would only refine a correction too small to matter.
    bias = bootstrap_bias(layout, p_hat, x, tau, residual_fn, noise.take(slice(0, 1)))
    ratio = float(np.max(np.abs(bias) / param_sigma))
    if ratio <= NEGLIGIBLE_BIAS_SIGMAS:
        return BiasCorrection(bias, 1, True, ratio)
    bias = 0.5 * (bias + bootstrap_bias(layout, p_hat, x, tau, residual_fn, noise.take(slice(1, PAIRS))))
    ratio = float(np.max(np.abs(bias) / param_sigma))
    if ratio <= LINEAR_BIAS_SIGMAS:
        return BiasCorrection(bias, 1, True, ratio)
    if not ratio <= GIVE_UP_SIGMAS:
        return BiasCorrection(bias, 1, False, ratio)
    for iteration in range(2, MAX_ITERATIONS + 1):
        # the same noise draws at every step: the bias becomes a smooth function of the
        # parameters, so the substitution converges instead of wandering with Monte Carlo noise
        candidate = p_hat - bias
        means = pair_means(layout, candidate, x, tau, residual_fn, noise)
        new = bias + RELAXATION * ((means.mean(axis=0) - candidate) - bias)  # the bias at the candidate
        step = float(np.max(np.abs(new - bias) / param_sigma))
        bias = new
        largest = float(np.max(np.abs(bias) / param_sigma)) if np.all(np.isfinite(bias)) else np.inf
        if largest > GIVE_UP_SIGMAS:
            break  # running away: no fixed point near the data, stop spending time on it
        if step <= SETTLED_SIGMAS:
            return BiasCorrection(bias, iteration, True, largest, noise, np.cov(means.T))
    return BiasCorrection(bias, iteration, False, largest)


def corrected_covariance(layout: mdl.Layout, p_hat: NDArray, correction: BiasCorrection, x: NDArray,
                         tau: NDArray | None, residual_fn, cov_hat: NDArray, directions: int = 2) -> NDArray:
    """Covariance of the corrected estimate ``p* = p̂ − b(p*)``: (I + B′)⁻¹ Σ (I + B′)⁻ᵀ.

    Why: where the bias had to be iterated away the problem is far from linear, and two things
    the covariance at a single point misses matter:

    * the bias depends on the parameters (B′ = ∂b/∂p), so the correction scales the estimate's
      scatter along the poorly determined directions by 1/(1 + B′).  B′ is measured, with the
      same noise draws, along the ``directions`` largest principal axes of Σ̂;
    * the estimate scatters more than its linearisation Σ̂ says: to second order p̂ = p + L·n +
      Q(n, n), and the quadratic term adds its own variance.  An antithetic pair's mean refit is
      p + Q(n, n), so the spread of the pairs' means measures it: Σ = Σ̂ + Σ_Q·(1 + 1/pairs), the
      last term being the Monte Carlo error of the bias estimated from those pairs.
    """
    assert correction.noise is not None
    p_star = p_hat - correction.bias
    w, vecs = np.linalg.eigh(cov_hat)
    j = np.eye(len(p_hat))
    for lam, v in list(zip(w, vecs.T, strict=True))[::-1][:directions]:
        eps = 0.5 * np.sqrt(max(lam, 0.0))
        if eps <= 0:
            continue
        shifted = bootstrap_bias(layout, p_star + eps * v, x, tau, residual_fn, correction.noise)
        j += np.outer((shifted - correction.bias) / eps, v)
    j_inv = np.linalg.inv(j)
    total = cov_hat
    if correction.pair_cov is not None:
        total = cov_hat + correction.pair_cov * (1.0 + 1.0 / len(correction.noise))
    return j_inv @ total @ j_inv.T
