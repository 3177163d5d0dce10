"""The drift test's false-alarm rate on the simulators' own motions (issue 28, open finding).

Good units (the fit benchmark's distortions, 0.3 µT noise, no drift) moved as the simulated flight
controllers move (``tumble``: the field sweeps pole to pole while the unit spins, so the direction
seen follows time; speed 0.5–2), read at 25 and 50 Hz; the first ``--readings`` of each, when they
reach the coverage target, fitted as the station fits them.  Printed: the drift statistic's share
above χ²₃'s 95 % point (nominal 5 %) and its mean (nominal 3) — once with the readings in their time
order, once with the same readings shuffled in time (the same coverage, no path in time).

    python benchmarks/drift_null.py [--units 400] [--readings 150] [--seed 9]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from magline.core.fit import coverage_of
from magline.core.synthetic import random_truth

sys.path.insert(0, str(Path(__file__).parent))
from early_stop import BINS, TARGET, fit
from fit_benchmark import FIELD, E

CHI2_3_P95 = 7.815


def statistics(units: int, readings: int, rng: np.random.Generator, shuffled: bool) -> np.ndarray:
    from magline.core.synthetic.imu import simulator_fields

    out = []
    field_ned = E / np.linalg.norm(E) * FIELD
    for _ in range(units):
        truth = random_truth(rng)
        speed, rate = float(rng.uniform(0.5, 2.0)), float(rng.choice([25.0, 50.0]))
        t = np.arange(readings) / rate + rng.uniform(0.0, 8.0)
        body = simulator_fields("tumble", t, speed, field_ned)
        m = truth.read(body, rng)
        if shuffled:
            m = m[rng.permutation(len(m))]
        if coverage_of(m, BINS) < TARGET:
            continue
        found = fit(m, t * 1000.0)
        if found is not None and found.drift and found.drift.get("statistic") is not None:
            out.append(found.drift["statistic"])
    return np.array(out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--units", type=int, default=400)
    parser.add_argument("--readings", type=int, default=150)
    parser.add_argument("--seed", type=int, default=9)
    args = parser.parse_args()
    for shuffled in (False, True):
        s = statistics(args.units, args.readings, np.random.default_rng(args.seed), shuffled)
        above = float(np.mean(s > CHI2_3_P95))
        print(f"{'shuffled in time' if shuffled else 'in time order   '}: {s.size} units judged, drift statistic "
              f"above χ²₃'s 95 % point {above:.1%} (nominal 5 %, ±{np.sqrt(0.05 * 0.95 / s.size):.1%}), "
              f"mean {s.mean():.2f} (nominal 3), median {np.median(s):.2f} (2.37)", flush=True)


if __name__ == "__main__":
    main()
