"""Two costs every unit or station pays, before and after their cheaper forms (printed, never asserted).

1. A new SQLite results store: migrated step by step by alembic (what every new store cost), against a copy
   of an empty store migrated once per process (``core/results/new_sqlite.py``, what a station does now);
   the median over ``--stores`` new files, the first copy apart (it migrates the template).
2. The accelerometer's smoothing spline the mounting check evaluates (``GravityTrack.at``): one spline per
   axis, as it was built, against one spline of three columns, as it is now, on a tumble's ``--readings``
   accelerometer readings at 50 Hz; and the largest difference between the two (they are the same spline).

    python benchmarks/store_and_spline.py [--stores 10] [--readings 600] [--repeat 20]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.interpolate import make_smoothing_spline
from sqlalchemy import create_engine

from magline.core.mounting.skew import SMOOTHING, GravityTrack
from magline.core.results import schema_version
from magline.core.results.new_sqlite import create_at_head


def store_figures(folder: Path, stores: int) -> None:
    migrated = []
    for n in range(stores):
        engine = create_engine(f"sqlite:///{folder / f'migrated-{n}.sqlite'}")
        started = time.perf_counter()
        schema_version.upgrade(engine, "benchmark")
        migrated.append(time.perf_counter() - started)
        engine.dispose()
    copied = []
    for n in range(stores):
        started = time.perf_counter()
        assert create_at_head(folder / f"copied-{n}.sqlite")
        copied.append(time.perf_counter() - started)
    print(f"new SQLite store, {stores} each: migrated step by step {statistics.median(migrated) * 1000:7.1f} ms "
          f"(median); a copy of the migrated template {statistics.median(copied[1:] or copied) * 1000:6.1f} ms "
          f"(median from the second; the first, which migrates the template, {copied[0] * 1000:.0f} ms)")


def spline_figures(readings: int, repeat: int) -> None:
    rng = np.random.default_rng(7)
    t_ms = np.arange(readings) * 20.0 + rng.normal(0.0, 0.5, readings)
    t_ms.sort()
    angle = np.cumsum(rng.normal(0.0, 0.05, (readings, 2)), axis=0)
    accel = 9.81 * np.column_stack([np.sin(angle[:, 0]), np.sin(angle[:, 1]) * np.cos(angle[:, 0]),
                                    np.cos(angle[:, 1]) * np.cos(angle[:, 0])]) + rng.normal(0.0, 0.3, (readings, 3))
    track = GravityTrack.of(t_ms, accel)
    lam = SMOOTHING * track.period_ms**3
    when = np.linspace(track.t_ms[0], track.t_ms[-1], 2 * readings)

    def per_axis() -> np.ndarray:
        return np.column_stack([make_smoothing_spline(track.t_ms, track.accel[:, k], lam=lam)(when) for k in range(3)])

    def three_columns() -> np.ndarray:
        return make_smoothing_spline(track.t_ms, track.accel, lam=lam)(when)

    timings = {}
    for name, make in (("one spline per axis", per_axis), ("one spline of three columns", three_columns)):
        runs = []
        for _ in range(repeat):
            started = time.perf_counter()
            make()
            runs.append(time.perf_counter() - started)
        timings[name] = statistics.median(runs)
    difference = float(np.max(np.abs(per_axis() - three_columns())))
    print(f"accelerometer spline, {readings} readings, median of {repeat}: "
          + "; ".join(f"{name} {seconds * 1000:.1f} ms" for name, seconds in timings.items())
          + f"; largest difference {difference:.2e} m/s²")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--stores", type=int, default=10)
    parser.add_argument("--readings", type=int, default=600)
    parser.add_argument("--repeat", type=int, default=20)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        store_figures(Path(tmp), args.stores)
    spline_figures(args.readings, args.repeat)


if __name__ == "__main__":
    main()
