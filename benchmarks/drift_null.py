"""The drift test's false-alarm rate on the simulators' own motions (issue 28).

Good units (the fit benchmark's distortions, 0.1–0.6 µT noise, the int16 milligauss wire, no drift)
moved as the simulated flight controllers move them (``tumble``: the field sweeps pole to pole at an
even pace while the unit spins; ``gimbal``: the same in eight pitch steps; speed 0.5–2), read at 10, 25
and 50 Hz from a random point of the sweep; the first ``--readings`` of each that reach the coverage
target, fitted as the station fits them.

Printed per motion: how many units the test could judge (on readings where a drift cannot be told
from a soft-iron change it does not, see ``_drift_separation`` in core/fit/geometric.py), and of
those the share above the 95 % and 99 % points of the statistic's reference 3·F(3, dof) (nominal 5 %
and 1 %), the count above its 10⁻³ threshold, its mean (nominal about 3) and median (about 2.4) —
once with the readings in time order, once shuffled in time (the same coverage, no path in time).

    python benchmarks/drift_null.py [--units 1000] [--readings 150 300] [--seed 9]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.stats import f as f_distribution

from magline.core.fit import coverage_of
from magline.core.links.readings import untruncate_mg
from magline.sim.truth import random_truth

sys.path.insert(0, str(Path(__file__).parent))
from early_stop import BINS, TARGET, fit
from fit_benchmark import FIELD, E

PARAMETERS = 12  # the full soft iron, the offset and its drift


def statistics(motion: str, units: int, readings: int, rng: np.random.Generator, shuffled: bool):
    """(statistic, its reference's 95 %, 99 % and 10⁻³ points) per judged unit, and the count not judged."""
    from magline.sim.truth.imu import simulator_fields

    out, not_judged = [], 0
    field_ned = E / np.linalg.norm(E) * FIELD
    for _ in range(units):
        truth = random_truth(rng, noise_ut=float(rng.uniform(0.1, 0.6)))
        speed, rate = float(rng.uniform(0.5, 2.0)), float(rng.choice([10.0, 25.0, 50.0]))
        t = np.arange(readings) / rate + rng.uniform(0.0, 16.0)
        m = truth.read(simulator_fields(motion, t, speed, field_ned), rng)
        m = untruncate_mg(np.trunc(m * 10.0)) / 10.0  # the firmware's int16 mG, undone as the backends do
        if shuffled:
            m = m[rng.permutation(len(m))]
        if coverage_of(m, BINS) < TARGET:
            continue
        found = fit(m, t * 1000.0)
        if found is None or not found.drift:
            continue
        if not found.drift["judged"]:
            not_judged += 1
            continue
        dof = found.samples_used - PARAMETERS
        out.append((found.drift["statistic"], *(3.0 * f_distribution.ppf(q, 3, dof) for q in (0.95, 0.99, 0.999))))
    return np.array(out).reshape(-1, 4), not_judged


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--units", type=int, default=1000)
    parser.add_argument("--readings", type=int, nargs="+", default=[150, 300])
    parser.add_argument("--seed", type=int, default=9)
    args = parser.parse_args()
    for motion in ("tumble", "gimbal"):
        for readings in args.readings:
            for shuffled in (False, True):
                s, skipped = statistics(motion, args.units, readings, np.random.default_rng(args.seed), shuffled)
                n = len(s)
                p95, p99 = (float(np.mean(s[:, 0] > s[:, k])) for k in (1, 2))
                alarms = int(np.sum(s[:, 0] > s[:, 3]))
                print(f"{motion:6s} {readings:3d} readings, {'shuffled  ' if shuffled else 'time order'}: "
                      f"judged {n}, not {skipped}; above 95 % {p95:5.1%} (±{np.sqrt(0.05 * 0.95 / n):.1%}), "
                      f"above 99 % {p99:4.1%} (±{np.sqrt(0.01 * 0.99 / n):.1%}), above 10⁻³ {alarms}, "
                      f"mean {s[:, 0].mean():.2f}, median {np.median(s[:, 0]):.2f}", flush=True)


if __name__ == "__main__":
    main()
