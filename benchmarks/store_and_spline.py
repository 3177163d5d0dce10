"""Two costs every unit or station pays, before and after their cheaper forms (printed, never asserted).

1. A new SQLite results store: migrated step by step by alembic (what every new store cost), against a copy
   of an empty store migrated once per process (``core/results/new_sqlite.py``, what a station does now);
   the median over ``--stores`` new files, the first copy apart (it migrates the template).
2. The accelerometer's smoothing spline the mounting check evaluates (``GravityTrack.at``), made and
   evaluated at twice its readings: SciPy's ``make_smoothing_spline`` one axis at a time, SciPy's of three
   columns, and magline's own (``core/mounting/smoothing.py``, what the check uses), on a tumble's
   ``--readings`` accelerometer readings at 50 Hz (and ten times as many: a long tumble at 100 Hz); and the
   largest difference from SciPy's (they are the same spline).
3. One whole mounting estimate (``estimate_mounting``) on a tumble of that length: the median of ``--repeat``.

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

from magline.core.mounting.estimate import ImuSeries, estimate_mounting
from magline.core.mounting.skew import SMOOTHING, GravityTrack
from magline.core.mounting.smoothing import SmoothingSpline
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

    def magline_own() -> np.ndarray:
        return SmoothingSpline.fit(track.t_ms, track.accel, lam)(when)

    timings = {}
    for name, make in (("SciPy per axis", per_axis), ("SciPy of three columns", three_columns),
                       ("magline's", magline_own)):
        runs = []
        for _ in range(repeat):
            started = time.perf_counter()
            make()
            runs.append(time.perf_counter() - started)
        timings[name] = statistics.median(runs)
    difference = max(float(np.max(np.abs(per_axis() - three_columns()))),
                     float(np.max(np.abs(magline_own() - three_columns()))))
    print(f"accelerometer spline, {readings} readings, median of {repeat}: "
          + "; ".join(f"{name} {seconds * 1000:.1f} ms" for name, seconds in timings.items())
          + f"; largest difference from SciPy's {difference:.2e} m/s²")


def estimate_figures(readings: int, repeat: int) -> None:
    """A good unit's tumble (its sensor turned 0.5° about x), the compass at 10 Hz stamped 40 ms before it
    was read, the accelerometer at 50 Hz: one mounting estimate, searched and refined."""
    from magline.sim.truth.imu import skewed_tumble

    rng = np.random.default_rng(11)
    mounted = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(0.0087), -np.sin(0.0087)], [0.0, np.sin(0.0087), np.cos(0.0087)]])
    mag, t_mag, accel, t_acc, _ = skewed_tumble(mounted, rng, rate_dps=90.0, seconds=readings / 50.0, skew_s=0.04)
    imu = ImuSeries(t_ms=t_acc, accel_mss=accel)
    runs = []
    for _ in range(repeat):
        started = time.perf_counter()
        found = estimate_mounting(mag, t_mag, ImuSeries(t_ms=imu.t_ms, accel_mss=imu.accel_mss))
        runs.append(time.perf_counter() - started)
    print(f"mounting estimate, {len(t_acc)} accelerometer and {len(t_mag)} compass readings: "
          f"{statistics.median(runs) * 1000:.0f} ms (median of {repeat}); skew {found.skew_ms:.1f} ms")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--stores", type=int, default=10)
    parser.add_argument("--readings", type=int, default=600)
    parser.add_argument("--repeat", type=int, default=20)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        store_figures(Path(tmp), args.stores)
    for readings in (args.readings, 10 * args.readings):
        spline_figures(readings, args.repeat)
    for readings in (args.readings, 10 * args.readings):
        estimate_figures(readings, max(3, args.repeat // 4))


if __name__ == "__main__":
    main()
