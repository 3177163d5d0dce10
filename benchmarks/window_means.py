"""Readings that are each the mean of the field over the time since the one before (ArduPilot's compasses),
fitted as plain readings and as window means, against known truth.

The unit turns at ``--rate`` °/s about an axis that itself sweeps every direction in ``--seconds``; the field is
sampled 100 times a second and handed on as the mean of each tenth of a second (ArduCopter's 100 Hz driver read
at 10 Hz).  Each compass reading carries ``--noise`` µT.  Printed for each way of fitting: the soft-iron
error's rms over the σ the fit states, per element (1 is honest), the largest element's mean error in its σ,
and the share of fits whose drift test called a warm-up (its own false alarm is 10⁻³).

    python benchmarks/window_means.py [--fits 200] [--rate 80] [--noise 0.02] [--seconds 60] [--seed 1]
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy.spatial.transform import Rotation

from magline.core.fit import FitOptions, fit_calibration

FIELD_NED = np.array([20.0, 0.0, 45.0])
A = np.array([[1.05, 0.02, -0.01], [0.02, 0.97, 0.03], [-0.01, 0.03, 1.01]])  # raw = A·b + h
HARD = np.array([12.0, -30.0, 8.0])
SAMPLE_HZ, READ_HZ = 100, 10


def window_means(rate_dps: float, seconds: float) -> tuple[np.ndarray, np.ndarray]:
    """The mean body field of each window (µT) and each window's end (ms)."""
    dt = 1.0 / SAMPLE_HZ
    t = np.arange(int(seconds * SAMPLE_HZ)) * dt
    polar, azimuth = np.arccos(1 - 2 * t / seconds), 2 * np.pi * 7 * t / seconds
    axis = np.stack([np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth), np.cos(polar)], axis=1)
    steps = Rotation.from_rotvec(axis * np.radians(rate_dps) * dt)
    attitude, attitudes = Rotation.identity(), []
    for step in steps:
        attitudes.append(attitude)
        attitude = attitude * step
    per = SAMPLE_HZ // READ_HZ
    body = Rotation.concatenate(attitudes).inv().apply(FIELD_NED).reshape(-1, per, 3)
    return body.mean(axis=1), t.reshape(-1, per)[:, -1] * 1000.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--fits", type=int, default=200)
    parser.add_argument("--rate", type=float, default=80.0, help="°/s")
    parser.add_argument("--noise", type=float, default=0.02, help="µT per reading")
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    means, t_ms = window_means(args.rate, args.seconds)
    truth = np.linalg.inv(A)
    field = float(np.linalg.norm(FIELD_NED))
    print(f"{args.fits} fits of {len(means)} readings, {args.rate:g}°/s, {args.noise:g} µT noise")
    for label, sample_hz in (("as plain readings", 0.0), ("as window means", float(SAMPLE_HZ))):
        rng = np.random.default_rng(args.seed)
        z, warm_ups = [], 0
        for _ in range(args.fits):
            raw = means @ A.T + HARD + rng.normal(0.0, args.noise, means.shape)
            fit = fit_calibration(raw, FitOptions(field_ut=field, sample_rate_hz=sample_hz), t_ms=t_ms)
            z.append((fit.soft_iron - truth) / fit.soft_iron_sigma)
            warm_ups += "warm_up" in fit.rejected
        z_arr = np.array(z)
        rms = np.sqrt(np.mean(z_arr**2, axis=0))
        print(f"{label}: soft-iron error / stated σ, rms per element (1 = honest):")
        for row in rms:
            print("    " + "  ".join(f"{v:5.2f}" for v in row))
        print(f"    largest mean error {np.abs(z_arr.mean(axis=0)).max():.2f} σ; warm-up called in "
              f"{warm_ups} of {args.fits} fits")


if __name__ == "__main__":
    main()
