"""Results-store figures on SQLite and PostgreSQL (printed, never asserted).

    python benchmarks/results_store.py [--units 200] [--stations 8] [--records 1000000] [--skip-large]

1. Insert of one unit record with 600 raw samples (begin, one attempt, finish): median and p95
   (goal: p95 ≤ 20 ms).
2. ``--stations`` concurrent processes × ``--units`` units into one PostgreSQL database and into
   one SQLite file: records expected, lost, duplicated; units per second.
3. A store of ``--records`` synthetic unit records generated in bulk (server-side SQL): history of
   one serial (goal ≤ 50 ms) and the last 10,000 units of one part's numeric measurements (≤ 1 s).

PostgreSQL is a throwaway cluster started like the tests' (``tests/pg_server.py``).
"""

from __future__ import annotations

import argparse
import multiprocessing
import statistics
import sys
import tempfile
import time
import zlib
from pathlib import Path

import numpy as np
from sqlalchemy import create_engine, func, select, text

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))

from pg_server import cluster  # noqa: E402

from magline.core.fit.samples_csv import RawSamples, format_samples, parse_samples  # noqa: E402
from magline.core.measurements import CATALOGUE, POSSIBLE, Array, Numeric  # noqa: E402
from magline.core.record import AttemptRecord, Outcome, PhaseResult, RunRecord  # noqa: E402
from magline.core.results import raw_blob  # noqa: E402
from magline.core.results.reading import RunFilter  # noqa: E402
from magline.core.results.series import load_series  # noqa: E402
from magline.core.results.store import SqlStore  # noqa: E402
from magline.core.results.tables import runs  # noqa: E402

RNG = np.random.default_rng(1)
RAW = RawSamples(mag_ut=RNG.normal(scale=50, size=(600, 3)), t_ms=np.arange(600) * 20.0)
RESIDUALS = RNG.normal(scale=0.3, size=600)


def record(serial: str, part: str = "P-100", station: str = "st-1") -> RunRecord:
    r = RunRecord(serial=serial, part=part, station_id=station, line="L1", operator="op", software_version="bench",
                  limit_hash="0" * 16)
    r.attempts.append(AttemptRecord(attempt=1, samples=600, coverage=0.9, target=0.6, raw=RAW, accepted=True))
    r.measurements = [Numeric(name=n, value=float(RNG.normal()), unit=u, low=-5.0, high=5.0) for n, (u, _) in
                      CATALOGUE.items()] + [Array.of("residual_ut", RESIDUALS, {})]
    r.phases = [PhaseResult(name=p, outcome=Outcome.PASS, duration_s=0.1, log=["ok"]) for p in
                ("identify", "connect", "acquire", "fit", "validate", "persist", "verify", "record")]
    r.params_before = {f"CAL_MAG0_{a}OFF": 0.0 for a in "XYZ"}
    r.params_written = r.params_read_back = {f"CAL_MAG0_{a}OFF": float(RNG.normal()) for a in "XYZ"}
    r.verdict, r.finished = Outcome.PASS, "2026-11-24T00:00:00+00:00"
    return r


def store_one(store: SqlStore, r: RunRecord) -> None:
    store.begin(r)
    store.save_attempt(r, r.attempts[0])
    store.finish(r)


def insert_latency(url: str, n: int = 200) -> tuple[float, float]:
    store = SqlStore(create_engine(url), "bench")
    times = []
    for i in range(n):
        r = record(f"LAT-{i}")
        t = time.perf_counter()
        store_one(store, r)
        times.append((time.perf_counter() - t) * 1e3)
    store.close()
    return statistics.median(times), float(np.percentile(times, 95))


def _station(args: tuple[str, int, int]) -> None:
    url, station, units = args
    store = SqlStore(create_engine(url), "bench")
    for i in range(units):
        store_one(store, record(f"C-{station}-{i}", station=f"st-{station}"))
    store.close()


def concurrent(url: str, stations: int, units: int) -> tuple[int, int, int, float]:
    SqlStore(create_engine(url), "bench").close()  # migrate once, before the stations race
    t = time.perf_counter()
    with multiprocessing.get_context("spawn").Pool(stations) as pool:
        pool.map(_station, [(url, s, units) for s in range(stations)])
    elapsed = time.perf_counter() - t
    engine = create_engine(url)
    with engine.connect() as conn:
        rows = conn.execute(select(func.count()).select_from(runs).where(runs.c.serial.like("C-%"))).scalar_one()
        distinct = conn.execute(select(func.count(func.distinct(runs.c.serial))).where(
            runs.c.serial.like("C-%"))).scalar_one()
    engine.dispose()
    expected = stations * units
    return expected, expected - distinct, rows - distinct, expected / elapsed


# a measurement's value in SQL: uniform on (−1, 1) — every characteristic far from normal, so ``spc``
# fits the percentile method's shapes to each (its worst case) — or a stable line's: N(0, 1) (the sum of
# twelve uniforms less six, Irwin–Hall) for a figure that takes either sign, and log-normal, exp(N(0, 0.5)),
# for a magnitude bounded by 0 (a norm, a residual, an angle from the nearest orientation), which is
# skewed and goes to the Box-Cox method
UNIFORM = {"postgresql": "random() * 2 - 1", "sqlite": "random() / 9.2e18"}
NORMAL = {"postgresql": "(" + " + ".join(["random()"] * 12) + " - 6)",
          "sqlite": "((" + " + ".join(["(random() / 1.8446744e19 + 0.5)"] * 12) + ") - 6)"}


def line_value(engine: str, names: list[str]) -> str:
    """The SQL of a stable line's value for the measurement ``m.name`` (see :data:`NORMAL`)."""
    magnitudes = ", ".join(f"'{n}'" for n in names if POSSIBLE.get(n, (-np.inf, np.inf))[0] >= 0)
    return f"CASE WHEN m.name IN ({magnitudes}) THEN exp(0.5 * {NORMAL[engine]}) ELSE {NORMAL[engine]} END"


def bulk(url: str, n: int, values: str = "uniform") -> float:
    """n runs (parts P-0..P-9, serials S-0..), each with the catalogue's numeric measurements, their
    values ``uniform`` or a stable ``line``'s (:data:`UNIFORM`, :data:`NORMAL`)."""
    engine = create_engine(url)
    SqlStore(engine, "bench").close()
    names = sorted(CATALOGUE)
    draw = UNIFORM if values == "uniform" else {e: line_value(e, names) for e in ("postgresql", "sqlite")}
    t = time.perf_counter()
    with engine.begin() as conn:
        if engine.dialect.name == "postgresql":
            conn.execute(text(
                "INSERT INTO runs (run_uuid, serial, part, station_id, line, started, verdict) "
                "SELECT md5(g::text), 'S-' || g, 'P-' || (g % 10), 'st-' || (g % 8), 'L1', "
                "to_char(timestamp '2026-01-01' + g * interval '1 second', 'YYYY-MM-DD\"T\"HH24:MI:SS'), 'pass' "
                "FROM generate_series(1, :n) g"), {"n": n})
            conn.execute(text(
                "INSERT INTO measurements (run_id, name, kind, value, verdict) "
                f"SELECT r.id, m.name, 'numeric', {draw['postgresql']}, 'pass' FROM runs r "
                "CROSS JOIN unnest(CAST(:names AS text[])) AS m(name) "
                "WHERE r.serial LIKE 'S-%'"), {"names": names})
        else:
            conn.execute(text(
                "WITH RECURSIVE g(x) AS (SELECT 1 UNION ALL SELECT x + 1 FROM g WHERE x < :n) "
                "INSERT INTO runs (run_uuid, serial, part, station_id, line, started, verdict) "
                "SELECT hex(randomblob(16)), 'S-' || x, 'P-' || (x % 10), 'st-' || (x % 8), 'L1', "
                "strftime('%Y-%m-%dT%H:%M:%S', '2026-01-01', '+' || x || ' seconds'), 'pass' FROM g"), {"n": n})
            rows = " UNION ALL ".join(f"SELECT '{name}' AS name" for name in names)
            conn.execute(text(
                f"INSERT INTO measurements (run_id, name, kind, value, verdict) SELECT r.id, m.name, 'numeric', "
                f"{draw['sqlite']}, 'pass' FROM runs r CROSS JOIN ({rows}) m WHERE r.serial LIKE 'S-%'"))
    with engine.connect().execution_options(isolation_level="AUTOCOMMIT") as conn:
        conn.execute(text("ANALYZE"))  # what autovacuum does after a bulk load: fresh planner statistics
    engine.dispose()
    return time.perf_counter() - t


def queries(url: str, rounds: int = 20) -> tuple[float, float]:
    store = SqlStore(create_engine(url), "bench")
    history = []
    for i in range(rounds):
        t = time.perf_counter()
        store.history(f"S-{1 + i * 4999}")
        history.append((time.perf_counter() - t) * 1e3)
    last = []
    with store.engine.connect() as conn:
        for i in range(5):
            t = time.perf_counter()
            series = load_series(conn, RunFilter(part=f"P-{i}"), last=10_000)
            last.append(time.perf_counter() - t)
            assert len(series) == 10_000 and len(series.values) == len(CATALOGUE)
    store.close()
    return statistics.median(history), statistics.median(last)


def raw_formats(rounds: int = 200) -> None:
    """Bytes per 600-sample attempt and encode / decode time: CSV text (what the store held before),
    compressed CSV, the .npy float32 blob (what it holds now), compressed .npy."""
    rng = np.random.default_rng(2)
    direction = rng.normal(size=(600, 3))
    direction /= np.linalg.norm(direction, axis=1)[:, None]
    samples = RawSamples(mag_ut=direction * 50 + rng.normal(scale=0.3, size=(600, 3)) + [120, -40, 30],
                         t_ms=np.arange(600) * 20.0 + rng.integers(-1, 2, 600),
                         temp_c=25 + rng.normal(scale=0.1, size=600))
    formats = {
        "csv text": (lambda s: format_samples(s).encode(), lambda b: parse_samples(b.decode())),
        "csv + zlib": (lambda s: zlib.compress(format_samples(s).encode()),
                       lambda b: parse_samples(zlib.decompress(b).decode())),
        "npy float32": (raw_blob.encode, raw_blob.decode),
        "npy + zlib": (lambda s: zlib.compress(raw_blob.encode(s)), lambda b: raw_blob.decode(zlib.decompress(b))),
    }
    print("0. raw samples of one attempt (600 readings with time and temperature)")
    for name, (encode, decode) in formats.items():
        blob = encode(samples)
        t = time.perf_counter()
        for _ in range(rounds):
            encode(samples)
        enc = (time.perf_counter() - t) / rounds * 1e3
        t = time.perf_counter()
        for _ in range(rounds):
            decode(blob)
        dec = (time.perf_counter() - t) / rounds * 1e3
        print(f"   {name:<12} {len(blob):6,} bytes   encode {enc:5.2f} ms   decode {dec:5.2f} ms")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--units", type=int, default=200)
    parser.add_argument("--stations", type=int, default=8)
    parser.add_argument("--records", type=int, default=1_000_000)
    parser.add_argument("--skip-large", action="store_true", help="skip the bulk store")
    parser.add_argument("--only-large", action="store_true", help="only the bulk store")
    parser.add_argument("--engines", default="sqlite,postgresql", help="comma list of sqlite, postgresql")
    args = parser.parse_args()
    if not args.only_large:
        raw_formats()
    with cluster() as pg, tempfile.TemporaryDirectory() as tmp:
        engines = {"sqlite": lambda name: f"sqlite:///{Path(tmp) / name}.sqlite",
                   "postgresql": lambda name: pg.new_database()}
        engines = {k: v for k, v in engines.items() if k in args.engines.split(",")}
        if args.only_large:
            args.units = 0
        if args.units:
            print("1. insert of one unit record (600 raw samples, 20 measurements + 600 residuals, params)")
        for kind, url in engines.items() if args.units else ():
            median, p95 = insert_latency(url("latency"))
            print(f"   {kind:<10} median {median:6.1f} ms   p95 {p95:6.1f} ms   (goal p95 ≤ 20 ms)")
        if args.units:
            print(f"2. {args.stations} concurrent station processes × {args.units} units into one store")
        for kind, url in engines.items() if args.units else ():
            expected, lost, duplicated, rate = concurrent(url("concurrent"), args.stations, args.units)
            print(f"   {kind:<10} {expected} records: {lost} lost, {duplicated} duplicated; {rate:6.1f} units/s")
        if not args.skip_large:
            print(f"3. a store of {args.records:,} unit records")
            for kind, url in engines.items():
                target = url("large")
                made = bulk(target, args.records)
                history_ms, last_s = queries(target)
                print(f"   {kind:<10} generated in {made:5.1f} s; history of one serial {history_ms:5.1f} ms "
                      f"(goal ≤ 50 ms); last 10,000 units of a part, numeric measurements {last_s:5.2f} s "
                      "(goal ≤ 1 s)")


if __name__ == "__main__":
    main()
