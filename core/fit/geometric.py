"""Maximum-likelihood hard/soft-iron fit: robust start, geometric refinement, honest uncertainty.

Why this design:
* Isotropic sensor noise makes the *geometric* distance of a raw sample to the ellipsoid Gaussian;
  minimising it (Sampson first-order distance, refined by Levenberg–Marquardt) is the ML estimate
  and reaches the Cramér–Rao bound, where algebraic quadric fits are biased on partial coverage.
* Spikes are removed by a robust scale (MAD) before the final, unweighted fit, so clean data lose
  no efficiency to a robust loss.
* The covariance from the final Jacobian is reported, and also decides whether the data determine
  the calibration at all: refusing undeterminable data beats returning confident garbage.
"""

from __future__ import annotations

import zlib

import numpy as np
from numpy.typing import NDArray

from magline.core.fit import model as mdl
from magline.core.fit.algebraic import AlgebraicFitError, fit_ellipsoid, fit_sphere
from magline.core.fit.coverage import coverage_of
from magline.core.fit.debias import corrected_covariance, estimate_bias
from magline.core.fit.objective import (
    geometric_residuals,
    normal_equations,
    prior_rows,
    residuals_and_jacobian,
    sampson_weights,
)
from magline.core.fit.quantiles import f_quantile
from magline.core.fit.radial import RadialUncertainty
from magline.core.fit.reading_window import at_window_middles, read_period_s, samples_per_read
from magline.core.fit.result import FitOptions, FitRefused, FitResult, warm_up_words
from magline.core.fit.screening import planarity, screen_samples
from magline.core.fit.solver import SETTLED_STEP, gauss_newton, levenberg_marquardt
from magline.core.fit.uncertainty import condition_number, direction_sigma_deg, soft_sigma

MIN_SAMPLES = {"full": 30, "diagonal": 20, "sphere": 12}
MAD_TO_SIGMA = 1.4826
BIAS_REFERENCE_SAMPLES = 600  # acquisition size at which bias is compared with σ
BOOTSTRAP_MAX_SAMPLES = 5000  # the bias bootstrap refits at most this many samples
REFINE_SUBSET_SAMPLES = 5000  # larger inputs are solved on a subset first, then polished on all
MAX_CENTRE_RADII = 10.0  # a centre this many field radii from the data's is a run-away, not a fit
MISFIT_P_VALUE = 1e-3  # F test: the full soft iron fits better than a diagonal (or sphere) model
# A re-weighting pass that moved the (normalised) parameters less than this is the last: the next
# one would move them about a thousand times less (the weights' sensitivity), far below 1e-4σ.
REWEIGHT_SETTLED = 1e-6
MAX_BIAS_SIGMAS = 10.0  # a settled bias beyond this many σ is not trusted to second order
# The drift test judges only readings on which an offset drift stands apart from a calibration: the
# share of its regressor no hard/soft iron can mimic, in units of the readings' noise relative to the
# field (see _drift_separation).  Measured on the simulators' tumble and gimbal (2,600 fits, 150 and 300
# readings): below 2 the share above χ²₃'s 95 % point was 20 %, 2–3 7 %, 3–5 3 %, 5–10 6 %, above 10 5–6 %.
# 5 is twice the onset; benchmarks/drift_null.py measures the rates at it.
DRIFT_SEPARATION_MIN = 5.0
ROTATE_MORE = "rotate the unit through more orientations (tumble about all three axes) and acquire again"
WAIT_FOR_WARM_UP = "leave the unit powered a little longer, then acquire again: its magnetometer is still warming up"


def fit_calibration(
    m_ut: NDArray,
    options: FitOptions | None = None,
    *,
    t_ms: NDArray | None = None,
    temp_c: NDArray | None = None,
) -> FitResult:
    """Fit ``h`` and ``S`` so that ``S·(m − h)`` lies on a sphere, or raise :class:`FitRefused`.

    ``m_ut`` is an (n, 3) array of raw samples in µT.  ``t_ms`` / ``temp_c`` (optional, per sample)
    let the fit model a linear warm-up drift of the offset; the offset reported is the end state.
    Readings that are each the mean of the driver's samples since the one before (``options.sample_rate_hz``,
    with ``t_ms``) are first taken back to the field at their window's middle (:mod:`.reading_window`).
    """
    opts = options or FitOptions()
    if opts.sample_rate_hz <= 0 or t_ms is None:
        return _fit_readings(m_ut, opts, t_ms, temp_c)
    raw = np.asarray(m_ut, dtype=float)
    window_s = read_period_s(t_ms)
    samples = samples_per_read(window_s, opts.sample_rate_hz)
    fixed = at_window_middles(raw, t_ms, window_s, samples)
    result = _fit_readings(fixed, opts, t_ms, temp_c)
    size = np.linalg.norm(np.nan_to_num(fixed - raw), axis=1)
    result.reading_window = {"window_s": window_s, "samples": samples,
                             "correction_rms_ut": float(np.sqrt(np.mean(size**2))) if len(size) else 0.0,
                             "correction_max_ut": float(size.max(initial=0.0))}
    return result


def _fit_readings(m_ut: NDArray, opts: FitOptions, t_ms: NDArray | None, temp_c: NDArray | None) -> FitResult:
    """The fit of the readings as given (:func:`fit_calibration` once each is a single sample)."""
    m = np.asarray(m_ut, dtype=float)
    if m.ndim != 2 or m.shape[1] != 3:
        raise ValueError(f"samples must be an (n, 3) array, got shape {m.shape}")
    screening = screen_samples(m, opts.range_ut)
    rejected = dict(screening.rejected)
    keep = screening.keep
    need = MIN_SAMPLES[opts.model]
    if keep.sum() < need:
        raise FitRefused("too_few_samples", f"only {int(keep.sum())} usable samples (need ≥ {need})",
                         "acquire for longer")

    centre, scale, inliers = _robust_sphere(m[keep], opts.outlier_sigmas)
    x_all = (m[keep] - centre) / scale
    inliers, quadric = _ellipsoid_screen(x_all, inliers, opts.outlier_sigmas)
    flat = planarity(x_all[inliers])
    if flat < opts.min_planarity:
        raise FitRefused("single_plane",
                         f"all samples lie in one plane (planarity {flat:.3f}): the unit was rotated "
                         "about a single axis", ROTATE_MORE)

    regressor, drift_name = _drift_regressor(t_ms, temp_c, keep)
    layout = mdl.Layout(opts.model, drift=False)
    log_ref = None if opts.field_ut is None else float(np.log(opts.field_ut / scale))
    if len(x_all) > REFINE_SUBSET_SAMPLES:
        p, inliers, sigma = _refine_large(layout, x_all, inliers, log_ref, opts)
    else:
        p0 = _initial_params(layout, x_all[inliers], log_ref, opts, quadric)
        p, inliers, sigma = _robust_refine(layout, p0, x_all, None, inliers, log_ref, opts)

    drift_info = None
    if regressor is not None and layout.model != "full":
        drift_info, p, inliers, sigma, layout = _drift_judged_with_full_model(
            layout, p, x_all, regressor, inliers, sigma, log_ref, opts, drift_name)
    elif regressor is not None:
        drift_info, p, inliers, sigma, layout = _maybe_drift(
            layout, p, x_all, regressor, inliers, sigma, log_ref, opts, drift_name)

    tau = regressor if layout.drift else None
    warm_up = drift_info.get("warm_up_excluded", 0) if drift_info else 0
    if warm_up:
        rejected["warm_up"] = warm_up
    n_out = int((~inliers).sum()) - warm_up
    if n_out:
        rejected["outlier"] = n_out
    if n_out > opts.max_outlier_fraction * len(x_all):
        raise FitRefused("not_ellipsoid",
                         f"{n_out} of {len(x_all)} samples do not lie on a common ellipsoid",
                         "keep motors off and magnets away during acquisition, then acquire again")

    x, tau_in = x_all[inliers], (tau[inliers] if tau is not None else None)
    cov, gram = _covariance(layout, p, x, tau_in, sigma, log_ref, opts)
    applied = None
    if opts.debias:
        p, cov, applied = _remove_bias(layout, p, x, tau_in, sigma, scale, log_ref, opts, cov)
    misfit = _restricted_model_cost(layout, p, x, sigma, scale, log_ref, opts)
    result = _assemble(layout, p, cov, gram, x, tau_in, centre, scale, keep, inliers, rejected, flat,
                       drift_info, opts, len(m), coverage_of(m, opts.coverage_bins), misfit)
    result.bias_correction = applied
    return result


def _remove_bias(layout, p, x, tau, sigma, scale, log_ref, opts, cov):
    """Remove the fit's O(σ²) bias, or refuse data whose estimate it dominates.

    ``cov`` is the covariance at ``p``.  Returns the corrected parameters, the covariance to
    report and what was done.  Where one estimate of the bias was enough (under half a σ) the
    covariance at ``p`` stands: at the corrected point it differs by far less than its own
    uncertainty.  Where the correction had to be iterated, its dependence on the parameters is
    propagated into the covariance.
    """
    # seeded from the data so that the same samples always give the same calibration
    rng = np.random.default_rng(zlib.crc32(x.tobytes()))
    x_boot, tau_boot = x, tau
    if len(x) > BOOTSTRAP_MAX_SAMPLES:
        # The σ² bias depends on the geometry and the noise, not on the count: a random subset
        # estimates it as well as all samples, at a fraction of the cost of refitting everything.
        subset = np.sort(rng.choice(len(x), BOOTSTRAP_MAX_SAMPLES, replace=False))
        x_boot, tau_boot = x[subset], (tau[subset] if tau is not None else None)
    cov_boot = cov * (len(x) / len(x_boot))  # the subset's covariance, to first order

    def objective(q, xs, w, with_jacobian):
        return residuals_and_jacobian(layout, q, xs, tau_boot, w, sigma, log_ref, opts, with_jacobian)

    # The σ² bias does not shrink with the sample count while σ does (1/√N), so "bias versus σ"
    # is judged at a standard acquisition size: a 100 000-sample tumble is not undetermined just
    # because its σ is tiny (the bias is removed below either way).
    sigma_ref = np.sqrt(np.clip(np.diag(cov_boot), 1e-30, None) * max(1.0, len(x_boot) / BIAS_REFERENCE_SAMPLES))
    correction = estimate_bias(layout, p, x_boot, tau_boot, sigma, objective, rng, sigma_ref)
    if not correction.settled or correction.largest_sigmas > MAX_BIAS_SIGMAS:
        # A second-order term that does not settle, or dwarfs the uncertainty: the problem is
        # not close to linear, i.e. the orientations seen do not determine the calibration.
        raise FitRefused("undetermined", "the orientations covered do not determine the calibration "
                         f"(the estimate is dominated by its own bias, {correction.largest_sigmas:.1f}σ)",
                         ROTATE_MORE)
    if correction.iterations > 1:  # the bias depends on the parameters: propagate that too
        cov = corrected_covariance(layout, p, correction, x_boot, tau_boot, objective, cov_boot)
        cov *= len(x_boot) / len(x)
    applied = {"iterations": correction.iterations, "largest_sigmas": round(correction.largest_sigmas, 3),
               "hard_iron_ut": [float(v) for v in -scale * correction.bias[:3]]}
    return p - correction.bias, cov, applied


# --------------------------------------------------------------------------- initialisation

def _robust_sphere(m: NDArray, k: float) -> tuple[NDArray, float, NDArray]:
    """Centre/scale for normalisation and a first inlier mask, from an iterated Kåsa fit."""
    inl = np.ones(len(m), dtype=bool)
    centre, radius = np.median(m, axis=0), 1.0
    for _ in range(4):
        try:
            used = m[inl]
            centre, radius = fit_sphere(used[:: max(1, len(used) // REFINE_SUBSET_SAMPLES)])  # a start only
        except AlgebraicFitError:
            break
        dist = np.linalg.norm(m - centre, axis=1) - radius
        mad = MAD_TO_SIGMA * np.median(np.abs(dist[inl] - np.median(dist[inl])))
        # the sphere ignores soft iron, so this first cut is deliberately generous
        new = np.abs(dist - np.median(dist[inl])) <= max(3 * k * mad, 0.02 * radius)
        if new.sum() < 10 or np.array_equal(new, inl):
            break
        inl = new
    if not np.isfinite(radius) or radius <= 0:
        radius = float(np.median(np.linalg.norm(m - centre, axis=1))) or 1.0
    return centre, float(radius), inl


def _ellipsoid_screen(x: NDArray, inliers: NDArray, k: float) -> tuple[NDArray, tuple | None]:
    """Tighten the sphere's generous first cut with an algebraic ellipsoid.

    The sphere cannot follow soft iron, so its cut must tolerate a few µT and lets through
    motor spikes of that size, which can lead the geometric fit astray.  The algebraic ellipsoid
    follows soft iron, leaving only noise, so the same k·σ cut then removes them.  Where the
    quadric is not an ellipsoid (too little coverage to tell), the sphere's cut stands.
    Returns the inliers and, when it was fitted to exactly those, the quadric (a starting point).
    """
    # The first quadric is fitted to the 90 % of samples nearest the sphere: a few large spikes
    # can tip an ordinary least-squares quadric into a non-ellipsoid, a trimmed one they cannot.
    off_sphere = np.abs(np.linalg.norm(x, axis=1) - 1.0)
    subset = inliers & (off_sphere <= np.quantile(off_sphere[inliers], 0.9))
    # a screen needs the quadric to a fraction of σ, which a few thousand samples give: larger
    # inputs are fitted on an even spread of them (and the quadric is then not a starting point)
    stride = max(1, len(x) // REFINE_SUBSET_SAMPLES)
    for _ in range(3):
        try:
            h, s = fit_ellipsoid(x[subset][::stride])
        except AlgebraicFitError:
            return inliers, None
        dist = np.linalg.norm((x - h) @ s, axis=1) - 1.0
        centre = np.median(dist[inliers])
        sigma = MAD_TO_SIGMA * np.median(np.abs(dist[inliers] - centre))
        new = np.abs(dist - centre) <= k * sigma
        if new.sum() < 0.5 * len(x):
            return inliers, None
        if np.array_equal(new, subset):
            return new, ((h, s) if stride == 1 else None)
        subset = new
    return subset, None


def _initial_params(layout: mdl.Layout, x: NDArray, log_ref: float | None, opts: FitOptions,
                    quadric: tuple | None = None) -> NDArray:
    """Start from the algebraic quadric when it is sane, else from a geometric sphere fit.

    The algebraic ellipsoid is excellent on a full tumble but wild on a cap or with outliers; the
    sphere fit is always sane and leads the geometric refinement into the right basin.
    ``quadric`` is the algebraic fit to exactly ``x`` when the caller already has it.
    """
    if layout.model != "sphere":
        try:
            h_alg, s_alg = quadric if quadric is not None else fit_ellipsoid(x)
            if np.all(np.abs(h_alg) < 0.5) and np.linalg.cond(s_alg) < 2.0:
                return mdl.pack(layout, h_alg, s_alg)
        except AlgebraicFitError:
            pass
    sphere = mdl.Layout("sphere", drift=False)
    try:
        p_sph = _solve(sphere, np.array([0.0, 0.0, 0.0, 1.0]), x, None, 0.01, log_ref, opts)
    except FitRefused:
        return mdl.pack(layout, np.zeros(3), np.eye(3))
    h_s, s_s, _ = mdl.unpack(sphere, p_sph)
    return mdl.pack(layout, h_s, s_s)


# --------------------------------------------------------------------------- refinement

def _solve(layout, p0, x, tau, sigma, log_ref, opts) -> NDArray:
    """Gradient-weighted least squares with the Sampson weights frozen per pass, re-weighted
    until they stop moving: the estimator whose O(σ²) bias the bootstrap reproduces (letting the
    weights vary inside one run minimises a different, more biased objective on partial coverage).
    """
    p = p0
    for _ in range(3):  # the weights depend (weakly) on p; two or three passes converge
        weights = mdl.gradient_norm(layout, p, x, tau)
        if not np.all(np.isfinite(weights)) or np.any(weights <= 0):
            raise FitRefused("not_ellipsoid", "the fit diverged", ROTATE_MORE)

        def objective(q, with_jacobian, w=weights):
            return residuals_and_jacobian(layout, q, x, tau, w, sigma, log_ref, opts, with_jacobian)

        # Gauss–Newton settles in two or three steps from an O(σ)-close start (the algebraic
        # quadric on a good tumble, the previous pass); LM takes over from a far one (caps).
        new = gauss_newton(objective, p)
        if new is None:
            new = levenberg_marquardt(objective, p, 1e-12)
        step = np.max(np.abs(new - p))
        p = new
        if step < REWEIGHT_SETTLED:
            break
    h, s, _ = mdl.unpack(layout, p)
    if not np.all(np.isfinite(p)) or np.any(np.linalg.eigvalsh(s) <= 0) or np.linalg.norm(h) > MAX_CENTRE_RADII:
        raise FitRefused("not_ellipsoid", "the samples do not describe an ellipsoid", ROTATE_MORE)
    return p


def _robust_refine(layout, p, x_all, tau_all, inliers, log_ref, opts):
    sigma = _robust_sigma(geometric_residuals(layout, p, x_all[inliers], _take(tau_all, inliers)))
    for _ in range(5):
        p = _solve(layout, p, x_all[inliers], _take(tau_all, inliers), sigma, log_ref, opts)
        r = geometric_residuals(layout, p, x_all, tau_all)
        sigma = _robust_sigma(r[inliers])
        new = np.abs(r) <= opts.outlier_sigmas * sigma
        if np.array_equal(new, inliers):
            break
        if new.sum() < MIN_SAMPLES[layout.model]:
            raise FitRefused("not_ellipsoid", "too few samples agree on one ellipsoid", ROTATE_MORE)
        inliers = new
    # r is at the final p over all samples (a last re-judging does not move p)
    sigma = float(np.std(r[inliers]))
    return p, inliers, max(sigma, 1e-12)


def _refine_large(layout, x_all, inliers, log_ref, opts):
    """The robust fit of a large acquisition: solved on a random subset, then polished on all.

    The subset's solution is within its (larger) uncertainty of the full-data one, where the
    problem is linear to far below the noise; Gauss–Newton steps on the normal equations (12
    unknowns, however many samples) then finish it at a fraction of the cost of a QR-based
    Levenberg–Marquardt run over every sample.
    """
    pick = np.sort(np.random.default_rng(zlib.crc32(x_all[:64].tobytes())).choice(
        len(x_all), REFINE_SUBSET_SAMPLES, replace=False))
    p = _initial_params(layout, x_all[pick][inliers[pick]], log_ref, opts)
    p, _, sigma = _robust_refine(layout, p, x_all[pick], None, inliers[pick], log_ref, opts)
    for _ in range(2):  # outliers judged on all samples with the polished model, then once more
        inliers = np.abs(geometric_residuals(layout, p, x_all, None)) <= opts.outlier_sigmas * sigma
        if inliers.sum() < MIN_SAMPLES[layout.model]:
            raise FitRefused("not_ellipsoid", "too few samples agree on one ellipsoid", ROTATE_MORE)
        p = _gauss_newton_polish(layout, p, x_all[inliers], sigma, log_ref, opts)
        r = geometric_residuals(layout, p, x_all[inliers], None)
        sigma = _robust_sigma(r)
    sigma = float(np.std(r))
    return p, inliers, max(sigma, 1e-12)


def _gauss_newton_polish(layout, p, x, sigma, log_ref, opts, max_steps: int = 6) -> NDArray:
    """Gauss–Newton steps with the Sampson weights frozen at each step's start (as :func:`_solve`).

    Each step takes the normal equations at its start (which also give the step's weights) and
    the trial point's ρ to decide whether the step is taken.
    """

    def with_priors(q):
        jtj, jtr, cost, w = normal_equations(layout, q, x, None)
        if log_ref is not None:
            r_prior, jac_prior = prior_rows(layout, q, sigma, log_ref, opts)
            jtj, jtr = jtj + jac_prior.T @ jac_prior, jtr + jac_prior.T @ r_prior
            cost += float(r_prior @ r_prior)
        return jtj, jtr, cost, w

    jtj, jtr, cost, weights = with_priors(p)
    for _ in range(max_steps):
        step = np.linalg.solve(jtj, jtr)
        q = p - step
        r_q = (mdl.radial(layout, q, x, None) - 1.0) / weights
        cost_q = float(r_q @ r_q)
        if log_ref is not None:
            r_prior, _ = prior_rows(layout, q, sigma, log_ref, opts)
            cost_q += float(r_prior @ r_prior)
        if not np.isfinite(cost_q) or cost_q > cost:
            break  # no further decrease: at the minimum to rounding
        p = q
        if float(np.max(np.abs(step))) <= SETTLED_STEP:
            break
        jtj, jtr, cost, weights = with_priors(p)
    return p


def _robust_sigma(r: NDArray) -> float:
    return max(float(MAD_TO_SIGMA * np.median(np.abs(r - np.median(r)))), 1e-12)


def _take(a: NDArray | None, mask: NDArray) -> NDArray | None:
    return None if a is None else a[mask]


# --------------------------------------------------------------------------- drift

def _drift_regressor(t_ms, temp_c, keep) -> tuple[NDArray | None, str | None]:
    """Normalised regressor τ ∈ [−1, 0] (0 = last sample) for a linear offset drift, or None."""
    for name, values, min_span in (("temp_c", temp_c, 0.5), ("t_ms", t_ms, 1000.0)):
        if values is None:
            continue
        v = np.asarray(values, float)[keep]
        if not np.all(np.isfinite(v)):
            continue
        span = float(v.max() - v.min())
        if span >= min_span:
            end = v[-1] if name == "t_ms" else v[np.argmax(np.abs(v - v[0]))]
            return (v - end) / span, name
    return None, None


def _maybe_drift(layout, p, x_all, tau_all, inliers, sigma, log_ref, opts, name):
    """Handle warm-up drift of the offset, tested with a likelihood-ratio test (p = drift_p_value).

    No significant drift: nothing changes.  Drift that dies out (warm-up): the earliest quarter,
    then half, of the acquisition is excluded until the rest shows none.  Drift that persists:
    a linear offset drift is modelled on the latest half and the end state reported.  Readings on
    which a drift cannot be told from the calibration (:func:`_drift_separation`) are not judged:
    ``judged`` False, and the stop rule waits for readings that can.
    """
    info: dict = {"regressor": name, "modelled": False, "warm_up_excluded": 0, "judged": True}
    drift_layout = mdl.Layout(layout.model, drift=True)
    for cut in (0.0, 0.25, 0.5):
        window = tau_all >= -1.0 + cut - 1e-12
        if cut > 0.0:
            try:
                p, inliers, sigma = _fit_window(layout, p, x_all, None, inliers, window, log_ref, opts)
            except FitRefused:
                break
            info["warm_up_excluded"] = int((~window).sum())
            info["cut"] = cut
        held = inliers & window
        separation = _drift_separation(layout, p, x_all[held], tau_all[held], sigma)
        if cut == 0.0:
            info["separation"] = separation
        if separation < DRIFT_SEPARATION_MIN:
            # The readings cannot tell a drift from a calibration: nothing to judge (at a cut, the
            # earlier readings' drift stands; what is left cannot say whether it goes on).
            info["judged"] = cut > 0.0
            return info, p, inliers, sigma, layout
        try:
            info["statistic"], drift_cov = _drift_statistic(layout, drift_layout, p, x_all[held], tau_all[held],
                                                            sigma, log_ref, opts)
        except FitRefused:
            break
        # The statistic divides by the noise estimated from the same readings: its exact reference
        # is 3·F(3, dof), a little wider than χ²₃ at a few hundred readings.
        info["threshold"] = 3.0 * f_quantile(1.0 - opts.drift_p_value, 3, max(int(held.sum()) - drift_layout.size, 1))
        info["detectable"] = _detectable_drift(drift_cov, info["threshold"])
        if info["statistic"] <= info["threshold"]:
            return info, p, inliers, sigma, layout
        if cut == 0.5:
            try:
                pd, inl_d, sigma_d = _fit_window(drift_layout, np.concatenate([p, np.zeros(3)]),
                                                 x_all, tau_all, inliers, window, log_ref, opts)
            except FitRefused:
                break
            info["modelled"] = True
            return info, pd, inl_d, sigma_d, drift_layout
    # Here only when a refit or a statistic was refused: with no statistic the drift was not judged;
    # after an alarm, the drift found could be neither set aside nor modelled — said, never passed
    # over as "no drift" (the stop rule waits on both, see core/fit/running.py).
    if "statistic" not in info:
        info["judged"] = False
    else:
        info["unresolved"] = True
    return info, p, inliers, sigma, layout


def _drift_separation(layout, p, x, tau, sigma) -> float:
    """How far an offset drift over ``tau`` stands apart from a change of the calibration, on these
    readings: the share of the drift's (Sampson-weighted) regressor that no hard/soft-iron change can
    mimic — the smallest singular value of its part orthogonal to the calibration's columns, over its
    largest column — divided by the readings' noise relative to the field (``sigma``, normalised).

    Why: where one body axis of the field moves linearly with time (a spiral sweeping pole to pole
    at an even pace, as the simulators' tumble and a motorised gimbal do, between reversals), a
    linear offset drift *is* a soft-iron change, exactly.  What tells them apart on such readings
    is the noise itself (the time is exact, the readings are not), and a likelihood ratio fitted to
    the noise is no χ²₃: on those tumbles 20–30 % of good units exceeded its 95 % point.  With the
    separation well above the noise, the ratio follows χ²₃ again (benchmarks/drift_null.py).
    """
    drift_layout = mdl.Layout(layout.model, drift=True)
    _, jac = mdl.radial_jacobian(drift_layout, np.concatenate([p, np.zeros(3)]), x, tau)
    jac = jac / sampson_weights(jac)[:, None]
    q, _ = np.linalg.qr(jac[:, :layout.size])
    drift_cols = jac[:, layout.size:]
    apart = drift_cols - q @ (q.T @ drift_cols)
    share = np.linalg.svd(apart, compute_uv=False).min() / max(np.linalg.norm(drift_cols, axis=0).max(), 1e-300)
    return float(share / max(sigma, 1e-300))


def _detectable_drift(drift_cov: NDArray, threshold: float) -> float:
    """The smallest offset drift over the readings (normalised units) the test catches half the
    time, in its least visible direction: the drift ``d`` whose expected statistic ``dᵀC⁻¹d`` just
    reaches the threshold along the largest axis of its covariance ``C``.

    Why: a drift below it passes unseen and bends the calibration beyond its predicted σ (the
    simulators' tumble separates a drift from soft iron poorly, benchmarks/early_stop.py
    ``--warm-up``); the record says how blind the test was, and a station may limit it."""
    return float(np.sqrt(threshold * max(float(np.linalg.eigvalsh(drift_cov).max()), 0.0)))


def _drift_statistic(layout, drift_layout, p, x, tau, sigma, log_ref, opts) -> tuple[float, NDArray]:
    """The likelihood-ratio statistic of a linear offset drift: ``(RSS₀ − RSS₁)/σ̂²`` with both models
    fitted by one estimator to **one** set of readings (the drift-free fit's inliers), so the models
    are nested and, without drift, the statistic follows χ²₃; and the drift's covariance (3 × 3,
    normalised units) under the drift model.

    Why one set: each model's robust refit chose its own inliers, and the residual sums of two
    different sets differed by more than any drift — at 100 readings the statistic was erratic
    (11.7, 12.9, then 1–3, once negative), a false alarm from a borderline reading."""
    p0 = _solve(layout, p, x, None, sigma, log_ref, opts)
    p1 = _solve(drift_layout, np.concatenate([p0, np.zeros(3)]), x, tau, sigma, log_ref, opts)
    rss0 = float(np.sum(geometric_residuals(layout, p0, x, None) ** 2))
    rss1 = float(np.sum(geometric_residuals(drift_layout, p1, x, tau) ** 2))
    s2 = rss1 / max(len(x) - drift_layout.size, 1)
    cov, _ = _covariance(drift_layout, p1, x, tau, sigma, log_ref, opts)
    return max(rss0 - rss1, 0.0) / max(s2, 1e-300), cov[-3:, -3:]


def _as_full(layout: mdl.Layout, p: NDArray) -> NDArray:
    """A restricted model's parameters as a full (drift-free) model's starting point."""
    h, s, _ = mdl.unpack(layout, p)
    return mdl.pack(mdl.Layout("full", drift=False), h, s)


def _drift_judged_with_full_model(layout, p, x_all, tau_all, inliers, sigma, log_ref, opts, name):
    """Drift handling for a diagonal / sphere model: decided with the full soft iron, applied to
    the restricted model.

    Why: a restricted model's misfit is smooth along the operator's motion, hence correlated with
    time, and a drift term would "explain" it; the full model has no such misfit to explain.
    """
    full = mdl.Layout("full", drift=False)
    try:
        pf = _solve(full, _as_full(layout, p), x_all[inliers], None, sigma, log_ref, opts)
    except FitRefused:
        return _maybe_drift(layout, p, x_all, tau_all, inliers, sigma, log_ref, opts, name)
    info, _, _, _, _ = _maybe_drift(full, pf, x_all, tau_all, inliers, sigma, log_ref, opts, name)
    cut = info.get("cut", 0.0)
    if cut == 0.0 and not info["modelled"]:
        return info, p, inliers, sigma, layout
    window = tau_all >= -1.0 + cut - 1e-12
    if info["modelled"]:
        layout, p = mdl.Layout(layout.model, drift=True), np.concatenate([p, np.zeros(3)])
    p, inliers, sigma = _fit_window(layout, p, x_all, tau_all if layout.drift else None, inliers, window,
                                    log_ref, opts)
    return info, p, inliers, sigma, layout


def _fit_window(layout, p, x_all, tau_all, inliers, window, log_ref, opts):
    """Robust refit on the samples inside ``window``; the returned inlier mask is over all samples."""
    idx = np.flatnonzero(window)
    p, inl, sigma = _robust_refine(layout, p, x_all[idx], _take(tau_all, window), inliers[idx], log_ref, opts)
    full = np.zeros(len(x_all), dtype=bool)
    full[idx[inl]] = True
    return p, full, sigma


# --------------------------------------------------------------------------- uncertainty & output

def _covariance(layout, p, x, tau, sigma, log_ref, opts):
    """Parameter covariance σ̂²·(JᵀJ)⁻¹ (σ̂ from the residuals) and the JᵀJ it came from."""
    gram, _, rss, _ = normal_equations(layout, p, x, tau)
    s2 = rss / max(len(x) - layout.size, 1)
    if log_ref is not None:  # prior rows, in units of the final noise estimate
        _, jac_prior = prior_rows(layout, p, np.sqrt(s2), log_ref, opts)
        gram = gram + jac_prior.T @ jac_prior
    try:
        cov = s2 * np.linalg.inv(gram)
    except np.linalg.LinAlgError as exc:
        raise FitRefused("undetermined", "the samples do not determine the calibration", ROTATE_MORE) from exc
    return cov, gram


def _restricted_model_cost(layout, p, x, sigma, scale, log_ref, opts) -> dict | None:
    """What a diagonal (or sphere) model loses against the full symmetric soft iron, or None.

    Why: an autopilot that holds only a diagonal gets the best axis-aligned fit, but a board whose
    soft iron is rotated leaves a systematic residual that is no fault of the operator's motion.
    Detected by an F test of the full model against the restricted one on the same samples; the
    cost is the largest angle between the two calibrations' field directions over those samples.
    """
    if layout.model == "full" or layout.drift:
        return None
    full = mdl.Layout("full", drift=False)
    try:
        pf = _solve(full, _as_full(layout, p), x, None, sigma, log_ref, opts)
        cov_f, _ = _covariance(full, pf, x, None, sigma, log_ref, opts)
    except FitRefused:
        return None
    r_restricted = geometric_residuals(layout, p, x, None)
    r_full = geometric_residuals(full, pf, x, None)
    extra, dof = full.size - layout.size, len(x) - full.size
    f_stat = ((r_restricted @ r_restricted - r_full @ r_full) / extra) / (r_full @ r_full / dof)
    if not f_stat > f_quantile(1.0 - MISFIT_P_VALUE, extra, dof):
        return None

    def directions(lay, q):
        hq, sq, _ = mdl.unpack(lay, q)
        c = (x - hq) @ sq
        return c / np.linalg.norm(c, axis=1, keepdims=True)

    cos = np.clip(np.einsum("ij,ij->i", directions(layout, p), directions(full, pf)), -1.0, 1.0)
    return {"model": layout.model, "residual_ut": float(np.std(r_restricted) * scale),
            "full_model_residual_ut": float(np.std(r_full) * scale),
            "direction_error_deg": float(np.degrees(np.arccos(cos.min()))),
            "full_model_direction_sigma_deg": direction_sigma_deg(full, pf, cov_f, x)}


def _assemble(layout, p, cov, gram, x, tau, centre, scale, keep, inliers, rejected, flat, drift_info,
              opts, n_total, coverage, misfit=None) -> FitResult:
    h_n, s_n, drift = mdl.unpack(layout, p)
    log_r, g = mdl.log_radius_and_gradient(layout, p)
    field_est = float(scale * np.exp(log_r))
    field_sigma = float(field_est * np.sqrt(max(g @ cov @ g, 0.0)))
    field_out = float(opts.field_ut) if opts.field_ut is not None else field_est
    s_out = s_n / scale * field_out
    h_out = centre + scale * h_n
    h_sigma = scale * np.sqrt(np.clip(np.diag(cov)[:3], 0, None))
    s_sigma = soft_sigma(layout, cov, field_out / scale)

    # Determinability: the reported uncertainty itself says whether the data pin the calibration
    # where it will be used — the calibrated field *direction* over the orientations seen.
    cond = condition_number(gram)
    dir_sigma = direction_sigma_deg(layout, p, cov, x[:: max(1, len(x) // REFINE_SUBSET_SAMPLES)])
    # A restricted model's misfit inflates its own σ; whether the motion determined the calibration
    # is then judged with the full model, which the misfit does not touch.
    judged_sigma = misfit["full_model_direction_sigma_deg"] if misfit else dir_sigma
    if not np.isfinite(cond) or not np.isfinite(judged_sigma) or judged_sigma > opts.max_direction_sigma_deg \
            or (misfit is None and np.linalg.norm(h_sigma) > opts.max_offset_sigma_fraction * field_est):
        uncertainty = f"heading 1σ up to {dir_sigma:.2f}°, offset 1σ {np.linalg.norm(h_sigma):.2f} µT"
        drifting = warm_up_words(drift_info)
        if drifting:  # the drift, not the motion, is what the data could not pin: rotating more would not help
            raise FitRefused("warm_up", f"{drifting}, and the calibration is not determined while it settles "
                             f"({uncertainty})", WAIT_FOR_WARM_UP)
        raise FitRefused("undetermined", f"the orientations covered do not determine the calibration ({uncertainty})",
                         ROTATE_MORE)
    axis_ratio = np.linalg.eigvalsh(s_out)
    if axis_ratio[-1] / axis_ratio[0] > opts.max_axis_ratio:
        raise FitRefused("not_ellipsoid",
                         f"implausible soft iron (axis ratio {axis_ratio[-1] / axis_ratio[0]:.2f})",
                         "check for a magnet or steel part next to the sensor")

    cal = (x - h_n - (np.outer(tau, drift) if tau is not None else 0.0)) @ s_n * field_out
    residuals = np.linalg.norm(cal, axis=1) - field_out
    geo = geometric_residuals(layout, p, x, tau) * scale
    noise = float(np.std(geo))
    fit_residual = misfit["full_model_residual_ut"] if misfit else np.sqrt(np.mean(geo**2))
    if fit_residual > opts.max_residual_fraction * field_est:
        raise FitRefused("not_ellipsoid",
                         f"residual {fit_residual:.2f} µT is too large for an ellipsoid of "
                         f"{field_est:.1f} µT", "keep motors off and magnets away, then acquire again")
    used = np.zeros(n_total, dtype=bool)
    used[np.flatnonzero(keep)[inliers]] = True
    ratio = ratio_sigma = None
    if opts.field_ut is not None:
        ratio = field_est / float(opts.field_ut)
        ratio_sigma = field_sigma / float(opts.field_ut)
    if drift_info is not None and "detectable" in drift_info:
        drift_info["detectable_ut"] = float(scale * drift_info.pop("detectable"))
    if drift_info is not None and drift_info.get("modelled"):
        drift_info["offset_change_ut"] = [float(v) for v in (-scale * drift)]
    return FitResult(
        model=layout.model, hard_iron_ut=h_out, soft_iron=s_out, field_ut=field_out,
        field_estimate_ut=field_est, field_sigma_ut=field_sigma, reference_field_ut=opts.field_ut,
        raw_to_reference_ratio=ratio, raw_to_reference_sigma=ratio_sigma,
        hard_iron_sigma_ut=h_sigma, soft_iron_sigma=s_sigma, residuals_ut=residuals, used=used,
        samples_total=n_total, rejected=rejected,
        coverage=coverage, coverage_bins=opts.coverage_bins,
        planarity=flat, condition_number=cond, direction_sigma_deg=dir_sigma, drift=drift_info,
        noise_ut=noise, model_misfit=misfit,
        radial=RadialUncertainty(layout, np.array(p, float), np.array(cov[:3 + layout.n_soft, :3 + layout.n_soft]),
                                 np.asarray(centre, float), float(scale), field_out),
    )
