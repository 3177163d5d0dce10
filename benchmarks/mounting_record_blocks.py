"""Whether the ArduCopter SITL swept unit's skew wanders through its tumble (docs/firmware.md, *ArduCopter*).

The record (``tests/fixtures/ardupilot-sitl-swept-record.npz``) is estimated as the station does; then, with
the mounting and inclination held at that estimate, the skew is fitted again in each of N stretches of the
tumble (equal spans of time), each with its σ from the cosine residuals' slope with the skew and the
estimate's own residual variance.  Printed per N: each stretch's skew and σ, and χ² per degree of freedom of
the stretches about their weighted mean (about 1 when one skew holds for the whole tumble; well above 1 when
the compass's timing wanders from stretch to stretch).

    python benchmarks/mounting_record_blocks.py [--blocks 5 8 10 13]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from scipy.optimize import minimize_scalar

from magline.core.mounting import ImuSeries, estimate_mounting
from magline.core.mounting.estimate import ROBUST_SCALE, residual_variance
from magline.core.mounting.orientations import rotation_angle_deg
from magline.core.mounting.skew import unit_rows

RECORD = Path(__file__).resolve().parents[1] / "tests" / "fixtures" / "ardupilot-sitl-swept-record.npz"
SLOPE_STEP_MS = 5.0  # the skew's step for the residuals' slope (a central difference)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--blocks", type=int, nargs="+", default=[5, 8, 10, 13])
    args = parser.parse_args()
    record = np.load(RECORD)
    imu = ImuSeries(t_ms=record["t_acc_ms"], accel_mss=record["accel_mss"].astype(float))
    mag, t = record["mag_cal"].astype(float), record["t_mag_ms"].astype(float)
    found = estimate_mounting(mag, t, imu)
    print(f"estimate: turned {rotation_angle_deg(found.data_to_body, np.eye(3)):.2f}° ± {found.sigma_deg:.2f}°, "
          f"skew {found.skew_ms:.1f} ± {found.own_skew_sigma_ms:.1f} ms (SITL's log: −46 ms, no turn)")
    track = imu.gravity_track()
    body = unit_rows(mag) @ found.data_to_body.T
    sine = np.sin(np.radians(found.inclination_deg))

    def residuals(rows: np.ndarray, skew: float) -> np.ndarray:
        return np.einsum("ij,ij->i", unit_rows(track.accel_at(t[rows] + skew)), body[rows]) + sine

    usable = np.flatnonzero(track.at(t + found.skew_ms)[1])
    variance = residual_variance(residuals(usable, found.skew_ms), 5)
    for blocks in args.blocks:
        edges = np.linspace(t[usable[0]], t[usable[-1]] + 1.0, blocks + 1)
        skews, sigmas = [], []
        for b in range(blocks):
            rows = usable[(t[usable] >= edges[b]) & (t[usable] < edges[b + 1])]
            def cost(skew: float, rows: np.ndarray = rows) -> float:  # robust, as the station's fit
                return float(np.sum(np.log1p((residuals(rows, skew) / ROBUST_SCALE) ** 2)))

            fit = minimize_scalar(cost, bounds=(found.skew_ms - 150.0, found.skew_ms + 150.0), method="bounded")
            step = SLOPE_STEP_MS
            slope = (residuals(rows, fit.x + step) - residuals(rows, fit.x - step)) / (2 * step)
            skews.append(float(fit.x))
            sigmas.append(float(np.sqrt(variance / max(float(slope @ slope), 1e-300))))
        s, w = np.array(skews), 1.0 / np.square(sigmas)
        chi2 = float(np.sum(w * (s - np.sum(w * s) / np.sum(w)) ** 2))
        print(f"{blocks:>2} stretches: χ²/dof {chi2 / (blocks - 1):4.2f}   skew (ms) "
              + "  ".join(f"{k:.0f}±{g:.0f}" for k, g in zip(skews, sigmas, strict=True)))


if __name__ == "__main__":
    main()
