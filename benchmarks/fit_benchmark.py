"""Fit accuracy and speed against known synthetic truth, side by side with the algebraic baseline.

Prints one row per scenario: RMS offset error (and the Cramér–Rao bound for the clean tumble),
soft-iron error (shape, scale removed), field error, heading error after calibration (median / max
over attitudes with up to ±30° tilt; for the clean tumble also the max reached by estimates drawn
from the Cramér–Rao bound, i.e. by an ideal efficient estimator), refusals; then the fit's speed.
Not a test: figures only.

    python benchmarks/fit_benchmark.py [--draws 200]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy.spatial.transform import Rotation

from magline.core.fit import FitOptions, FitRefused, fit_calibration
from magline.core.fit import model as mdl
from magline.core.fit.algebraic import AlgebraicFitError, fit_ellipsoid
from magline.core.synthetic import earth_field_ned, motion_directions, random_truth

FIELD, INCLINATION = 48.0, 62.0
E = earth_field_ned(FIELD, INCLINATION)


def attitudes() -> Rotation:
    yaw = np.deg2rad(np.arange(0, 360, 15))
    tilt = np.deg2rad(np.array([-30, -15, 0, 15, 30]))
    y, r, p = np.meshgrid(yaw, tilt, tilt, indexing="ij")
    return Rotation.from_euler("ZYX", np.column_stack([y.ravel(), p.ravel(), r.ravel()]))


ATT = attitudes()


def heading_errors(h, s, truth) -> np.ndarray:
    b = ATT.inv().apply(E)  # true body-frame field
    raw = np.linalg.solve(truth.soft_iron, b.T).T + truth.hard_iron_ut
    cal = (raw - h) @ s.T
    level_true, level_cal = ATT.apply(b), ATT.apply(cal)  # tilt-compensate with the known attitude
    hd_true = np.arctan2(level_true[:, 1], level_true[:, 0])
    hd_cal = np.arctan2(level_cal[:, 1], level_cal[:, 0])
    return np.degrees(np.abs((hd_cal - hd_true + np.pi) % (2 * np.pi) - np.pi))


def shape(s):
    return s / np.cbrt(np.linalg.det(s))


def crb(truth, d, rng) -> tuple[float, float]:
    """RMS offset bound, (JᵀJ)⁻¹σ² with J the geometric-distance Jacobian at the truth, and the
    heading max of one estimate drawn from that bound: what an efficient estimator achieves."""
    layout = mdl.Layout("full", drift=False)
    p = mdl.pack(layout, truth.hard_iron_ut / FIELD, truth.soft_iron)
    x = (np.linalg.solve(truth.soft_iron, (d * FIELD).T).T + truth.hard_iron_ut) / FIELD
    _, jac = mdl.radial_jacobian(layout, p, x, None)
    jac /= mdl.gradient_norm(layout, p, x, None)[:, None]
    cov = np.linalg.inv(jac.T @ jac) * (truth.noise_ut / FIELD) ** 2
    h, s, _ = mdl.unpack(layout, rng.multivariate_normal(p, cov))
    return float(np.sqrt(np.trace(cov[:3, :3]))) * FIELD, float(heading_errors(h * FIELD, s, truth).max())


SCENARIOS = {
    "clean tumble": dict(motion="hand_tumble"),
    "hemisphere": dict(motion="hemisphere"),
    "30% cap + ref": dict(motion="cap30", ref=True),
    "two rings": dict(motion="two_rings"),
    "2% spikes": dict(motion="hand_tumble", spikes=0.02),
    "clipped 15%": dict(motion="hand_tumble", clip=True),
    "single axis": dict(motion="single_axis"),
}


def run(name, cfg, draws, rng):
    off, soft, field, hd_med, hd_max, base_hd, bound_off, bound_hd, refused = [], [], [], [], [], [], [], [], 0
    for _ in range(draws):
        truth = random_truth(rng)
        d = motion_directions(cfg["motion"], 600, rng, E)
        m = truth.read(d * FIELD, rng)
        range_ut = None
        if cfg.get("clip"):
            range_ut = float(np.quantile(np.abs(m).max(axis=1), 0.85))
            m = np.clip(m, -range_ut, range_ut)
        if cfg.get("spikes"):
            k = int(cfg["spikes"] * len(m))
            idx = rng.choice(len(m), k, replace=False)
            v = rng.normal(size=(k, 3))
            m[idx] += v / np.linalg.norm(v, axis=1, keepdims=True) * rng.uniform(20, 200, (k, 1))
        if name == "clean tumble":
            b_off, b_hd = crb(truth, d, rng)
            bound_off.append(b_off)
            bound_hd.append(b_hd)
        try:
            c = m.mean(axis=0)
            h, s = fit_ellipsoid((m - c) / FIELD)
            hb, sb = c + h * FIELD, s
            base_hd.append(heading_errors(hb, sb, truth).max())
        except AlgebraicFitError:
            base_hd.append(np.nan)
        try:
            fit = fit_calibration(m, FitOptions(field_ut=FIELD if cfg.get("ref") else None, range_ut=range_ut))
        except FitRefused:
            refused += 1
            continue
        off.append(np.linalg.norm(fit.hard_iron_ut - truth.hard_iron_ut))
        soft.append(np.max(np.abs(shape(fit.soft_iron) - shape(truth.soft_iron))))
        field.append(fit.field_estimate_ut - FIELD * np.linalg.det(truth.soft_iron) ** (-1 / 3))
        he = heading_errors(fit.hard_iron_ut, fit.soft_iron, truth)
        hd_med.append(np.median(he))
        hd_max.append(he.max())
    rms = np.sqrt(np.mean(np.square(off))) if off else np.nan
    base = np.nanmax(base_hd) if np.isfinite(base_hd).any() else np.nan
    bound = np.sqrt(np.mean(np.square(bound_off))) if bound_off else np.nan
    bound_hd_max = np.max(bound_hd) if bound_hd else np.nan
    return (f"{name:<14} {rms:8.3f} {bound:7.3f} {np.mean(soft) if soft else np.nan:9.4f} "
            f"{np.mean(field) if field else np.nan:+8.3f} {np.median(hd_med) if hd_med else np.nan:7.3f} "
            f"{np.max(hd_max) if hd_max else np.nan:7.3f} {bound_hd_max:7.3f} {base:9.3f} {refused:4d}/{draws}")


def speed(rng):
    truth = random_truth(rng)
    out = []
    for n, reps in ((600, 30), (100_000, 3)):
        d = motion_directions("full_sphere", n, rng, E)
        m = truth.read(d * FIELD, rng)
        times = []
        for _ in range(reps):
            t = time.perf_counter()
            fit_calibration(m)
            times.append(time.perf_counter() - t)
        out.append(f"{n:>7} samples: median {np.median(times) * 1e3:8.1f} ms")
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--draws", type=int, default=200)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    print(f"{'scenario':<14} {'off rms':>8} {'CRB':>7} {'S shape':>9} {'field':>8} {'hd med':>7} "
          f"{'hd max':>7} {'CRB hdmx':>7} {'alg hdmax':>9} refused   (µT, µT, -, µT, °, °, °, °)")
    for name, cfg in SCENARIOS.items():
        print(run(name, cfg, args.draws, rng), flush=True)
    print("speed (in process):")
    for line in speed(rng):
        print("  " + line)


if __name__ == "__main__":
    main()
