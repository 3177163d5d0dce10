"""Process-quality figures (printed, never asserted), on SQLite and PostgreSQL.

    python benchmarks/process_quality.py [--records 1000000] [--engines sqlite,postgresql]

1. A store of ``--records`` synthetic unit records (as ``results_store.py`` makes them; ``--values``
   uniform — every characteristic non-normal, the percentile method's four shape fits for each, the
   worst case — and line, a stable line's: signed figures normal, magnitudes log-normal):
   ``magline spc --part P-1`` over its last 10,000 units, end to end as a separate process
   (interpreter start and imports included; goal ≤ 3 s, issue 45's), and the same report built
   in-process with the station file's limits, as the command builds it.
2. The in-run review check on that store: the history read (last 200 passing units of the part on
   the line) plus the robust band, per unit (goal ≤ 20 ms added to a unit).
3. One unit report (a real demo unit: 600 raw samples): generation time (goal ≤ 1 s) and file size
   (goal ≤ 6 MB; plotly.js alone is about 4.8 MB).
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml
from sqlalchemy import create_engine

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))
sys.path.insert(0, str(REPO / "benchmarks"))

from pg_server import cluster  # noqa: E402
from results_store import bulk  # noqa: E402

from magline.core.measurements import CATALOGUE, Numeric, Verdict  # noqa: E402
from magline.core.quality.review import review  # noqa: E402
from magline.core.quality.spc import build  # noqa: E402
from magline.core.results.reading import RunFilter  # noqa: E402
from magline.core.results.store import SqlStore  # noqa: E402


def station_file(folder: Path, results: dict) -> Path:
    cfg = yaml.safe_load((REPO / "stations" / "demo.yaml").read_text(encoding="utf-8"))
    cfg["results"] = results
    cfg["products"]["P-1"] = cfg["products"].pop("MOCK-100")
    cfg["default_part"] = "P-1"
    path = folder / "bench-station.yaml"
    path.write_text(yaml.safe_dump(cfg, sort_keys=False, allow_unicode=True), encoding="utf-8")
    return path


def spc_end_to_end(station: Path, env: dict[str, str], rounds: int = 3) -> float:
    times = []
    for _ in range(rounds):
        t = time.perf_counter()
        proc = subprocess.run([sys.executable, "-m", "magline.core.cli", "spc", "--station", str(station),
                               "--part", "P-1"], capture_output=True, text=True, env=env, timeout=300)
        times.append(time.perf_counter() - t)
        if proc.returncode != 0:
            raise RuntimeError(proc.stderr)
    return statistics.median(times)


def in_process(store: SqlStore, station: Path, rounds: int = 3) -> tuple[float, float]:
    """The read, and the read with the report built as ``magline spc`` builds it: the station file's
    limits applied, so the product characteristics are charted and their capability computed."""
    from magline.core.quality.commands import _with_station_limits
    from magline.core.station import load_station

    loaded = load_station(station)
    read, total = [], []
    for _ in range(rounds):
        t = time.perf_counter()
        series = store.series(RunFilter(part="P-1"), last=10_000, with_attempts=True)
        t1 = time.perf_counter()
        build(_with_station_limits(series, loaded, "P-1"), "bench",
              stop_determined=loaded.acquisition.stop == "determined")
        total.append(time.perf_counter() - t)
        read.append(t1 - t)
    return statistics.median(read), statistics.median(total)


def review_check(store: SqlStore, rounds: int = 50) -> tuple[float, float]:
    rng = np.random.default_rng(3)
    unit = [Numeric(n, float(rng.random()), u, None, None, Verdict.PASS) for n, (u, _) in CATALOGUE.items()]
    times = []
    for i in range(rounds):
        t = time.perf_counter()
        past = store.series(RunFilter(part=f"P-{i % 10}", line="L1", verdict="pass"), last=200,
                            names=[m.name for m in unit], with_limits=False)
        review(unit, past.values, units=len(past), min_units=30, sigma=3.0)
        times.append((time.perf_counter() - t) * 1e3)
    return statistics.median(times), float(np.percentile(times, 95))


def unit_report(folder: Path) -> tuple[float, float]:
    from magline.core.plugins import load_plugins
    from magline.core.reports.commands import write_report
    from magline.core.sequencer import Sequencer
    from magline.core.station import load_station

    cfg = yaml.safe_load((REPO / "stations" / "demo.yaml").read_text(encoding="utf-8"))
    cfg["products"]["MOCK-100"]["options"].update({"realtime": False, "seed": 1})
    cfg["results"] = {"sink": "sqlite", "path": "report-bench.sqlite"}
    path = folder / "report-station.yaml"
    path.write_text(yaml.safe_dump(cfg, sort_keys=False, allow_unicode=True), encoding="utf-8")
    seq = Sequencer(load_station(path), load_plugins(), folder, sleep=lambda s: None)
    try:
        record = seq.run_unit("REPORT-1")
        engine = seq.sink.record_engine
        times = []
        for _ in range(5):
            t = time.perf_counter()
            out = write_report(engine, str(record.run_id), folder / "report.html")
            times.append(time.perf_counter() - t)
    finally:
        seq.close()
    return statistics.median(times), out.stat().st_size / 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--records", type=int, default=1_000_000)
    parser.add_argument("--engines", default="sqlite,postgresql")
    parser.add_argument("--reuse", metavar="URL", help="a store already filled by results_store.bulk (no generation)")
    parser.add_argument("--values", default="uniform,line",
                        help="the measurements' values: uniform (every characteristic non-normal: the percentile "
                             "method's shape fits for each, the worst case) and/or line (a stable line's: signed "
                             "figures normal, magnitudes log-normal, which go to Box-Cox)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        seconds, size = unit_report(folder)
        print(f"3. unit report (600 raw samples): {seconds * 1e3:.0f} ms (goal ≤ 1 s), {size:.2f} MB (goal ≤ 6 MB)")
        with cluster() as pg:
            for engine, values in ((e, v) for e in args.engines.split(",") for v in args.values.split(",")):
                env = dict(os.environ)
                if args.reuse:
                    url = args.reuse
                    engine = url.split(":")[0].split("+")[0]
                if engine == "postgresql":
                    url = args.reuse or pg.new_database()
                    env["MAGLINE_BENCH_DB_URL"] = url
                    os.environ["MAGLINE_BENCH_DB_URL"] = url
                    station = station_file(folder, {"sink": "sql", "url_env": "MAGLINE_BENCH_DB_URL"})
                else:
                    url = args.reuse or f"sqlite:///{folder / f'large-{values}.sqlite'}"
                    station = station_file(folder, {"sink": "sqlite", "path": url.removeprefix("sqlite:///")})
                made = bulk(url, args.records, values) if not args.reuse else 0.0
                store = SqlStore(create_engine(url), engine)
                read, total = in_process(store, station)
                median, p95 = review_check(store)
                store.close()
                wall = spc_end_to_end(station, env)
                print(f"1. {engine:<10} {args.records:,} records, {values} values (generated in {made:.0f} s): magline "
                      f"spc over the last 10,000 units {wall:.2f} s end to end (goal ≤ 3 s, issue 45); in-process "
                      f"read {read:.2f} s, read + charts + rules + shape tests + capability {total:.2f} s")
                print(f"2. {engine:<10} in-run review check: median {median:.1f} ms, p95 {p95:.1f} ms "
                      "(goal ≤ 20 ms per unit)")


if __name__ == "__main__":
    main()
