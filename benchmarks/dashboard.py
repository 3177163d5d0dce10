"""How fast the dashboard's pages are over a large store, and how soon a recorded unit reaches its tile.

A SQLite store is filled with ``--runs`` units (ten stations on two lines, three parts, eight
measurements each, one a slow step), the dashboard served over it read-only, and Debian's Chromium opens
"the line now", a part's process page and a unit's page; each figure is the time from the request to the
page drawn (the tiles drawn, the first chart drawn, the load event), each opening in a new tab: the
median of ``--repeat`` openings with the browser's cache (plotly.js and the code compiled from it kept, as
a browser keeps them between visits), and apart, the first visit with nothing cached.  Then a unit
is written to the store as a station writes it and the delay until its tile shows it is timed.
``--url postgresql+psycopg://…`` fills and reads that database instead (it must be empty).

    python benchmarks/dashboard.py [--runs 10000] [--repeat 3] [--url URL | --postgres]

Goals (issue): ≤ 1 s per page at 1,000,000 runs on PostgreSQL, ≤ 2 s from a record to its tile.
Figures only, not a test.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
import urllib.request
import uuid
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np
from sqlalchemy import create_engine, insert, text

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from browser import Served, chromium, chromium_path, free_port, launch_flags

from magline.core.dashboard.app import create_app
from magline.core.dashboard.store import open_read_only
from magline.core.quality.trends import Shifts
from magline.core.results import schema_version
from magline.core.results.tables import measurements, runs

STATIONS = [(f"st-{i:02d}", "L1" if i < 5 else "L2") for i in range(10)]
PARTS = ["P-100", "P-200", "P-300"]
NAMES = [("hard_iron_norm_ut", 74.0, 0.5, 300.0), ("residual_rms_ut", 0.3, 0.05, 1.0),
         ("axis_ratio", 1.05, 0.01, 1.4), ("field_error_pct", 0.0, 0.5, 10.0),
         ("mounting_error_deg", 0.3, 0.1, 3.0), ("time_skew_ms", -31.0, 2.0, None),
         ("direction_sigma_deg", 0.1, 0.02, 0.5), ("coverage", 0.8, 0.05, None)]
BATCH = 5000


def fill(engine, count: int, rng: np.random.Generator) -> None:
    """``count`` runs over the last 30 days, the latest ones today."""
    now = datetime.now(UTC)
    start = now - timedelta(days=30)
    step = (now - start) / count
    for first in range(0, count, BATCH):
        ids = range(first + 1, min(first + BATCH, count) + 1)
        run_rows, m_rows = [], []
        for i in ids:
            station, line = STATIONS[i % len(STATIONS)]
            when = start + step * i
            verdict = "pass" if rng.random() > 0.03 else "fail"
            run_rows.append({"id": i, "run_uuid": str(uuid.uuid4()), "serial": f"SN-{i:07d}", "part": PARTS[i % 3],
                             "station_id": station, "line": line, "operator": "op", "software_version": "bench",
                             "limit_hash": "x", "started": (when - timedelta(seconds=20)).isoformat(
                                 timespec="milliseconds"), "finished": when.isoformat(timespec="milliseconds"),
                             "verdict": verdict, "unit_info": '{"firmware": "1.15.0"}'})
            drift = 1.0 if i > 0.8 * count else 0.0
            for name, centre, spread, high in NAMES:
                m_rows.append({"run_id": i, "name": name, "kind": "numeric", "unit": "",
                               "value": float(rng.normal(centre + drift * spread, spread)), "low": None,
                               "high": high, "verdict": "pass"})
        with engine.begin() as conn:
            conn.execute(insert(runs), run_rows)
            conn.execute(insert(measurements), m_rows)
    if engine.dialect.name == "postgresql":  # ids given explicitly: the sequence a station's insert draws from
        with engine.begin() as conn:
            conn.execute(text("SELECT setval(pg_get_serial_sequence('runs', 'id'), (SELECT max(id) FROM runs))"))


def timed(context, url: str, ready: str) -> float:
    """One opening of ``url`` from another page of the same server (as a person follows a link), in a new
    tab of ``context``, from the request to ``ready``.  Why the new tab and the page before: reloading one
    tab timed the previous page's teardown too, and a tab's first address started its renderer."""
    page = context.new_page()
    try:
        page.goto(url.split("?")[0].rsplit("/", 1)[0] + "/static/dashboard.css")
        started = time.perf_counter()
        page.goto(url, wait_until="commit")
        page.wait_for_function(ready, timeout=120_000)
        return time.perf_counter() - started
    finally:
        page.close()


def fetched(url: str) -> float:
    """Seconds from the request to the response's last byte, no browser: what the server takes."""
    started = time.perf_counter()
    with urllib.request.urlopen(url, timeout=120) as answer:
        answer.read()
    return time.perf_counter() - started


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=10_000)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--url", help="a PostgreSQL database to fill and read (default: a SQLite file)")
    parser.add_argument("--postgres", action="store_true",
                        help="start a throwaway PostgreSQL cluster (Debian's binaries, as the suite does) and use it")
    args = parser.parse_args()
    if args.postgres:
        from pg_server import cluster

        with cluster() as server:
            args.url = server.new_database()
            measure(args)
        return
    measure(args)


def measure(args: argparse.Namespace) -> None:
    rng = np.random.default_rng(68)
    with tempfile.TemporaryDirectory() as tmp:
        target = args.url or str(Path(tmp) / "line.sqlite")
        engine = create_engine(args.url or f"sqlite:///{target}")
        schema_version.upgrade(engine, "benchmark")
        started = time.perf_counter()
        fill(engine, args.runs, rng)
        print(f"{args.runs:,} runs written in {time.perf_counter() - started:.0f} s "
              f"({'PostgreSQL' if args.url else 'SQLite'})", flush=True)
        if args.url:  # the planner's statistics, as autovacuum gathers them within a minute of a bulk load
            with engine.connect() as conn:
                conn.execution_options(isolation_level="AUTOCOMMIT").execute(text("ANALYZE"))
        store = open_read_only(target)
        served = Served(create_app(store, Shifts()), free_port())
        try:
            with chromium() as browser:
                page = browser.new_page(viewport={"width": 1600, "height": 1000})
                pages = {"the line now": (served.url, "window.__shown >= 1"),
                         "a part's process": (served.url + "process?part=P-100",
                                              "document.querySelectorAll('.plotly-graph-div .main-svg').length > 0"),
                         "a unit": (served.url + f"unit?serial=sn-{args.runs // 2:07d}", "document.readyState === "
                                                                                          "'complete'")}
                for number, (name, (url, ready)) in enumerate(pages.items()):
                    # a browser profile of its own, as a person's browser keeps one: nothing cached at the
                    # first visit; then plotly.js and, from its third run, the code compiled from it
                    context = browser.browser_type.launch_persistent_context(
                        Path(tmp) / f"profile-{number}", executable_path=chromium_path(), args=launch_flags(),
                        viewport={"width": 1600, "height": 1000})
                    try:
                        first = timed(context, url, ready)
                        times = [timed(context, url, ready) for _ in range(args.repeat + 1)][1:]
                    finally:
                        context.close()
                    served_s = [fetched(url) for _ in range(args.repeat)]  # the server's part: the page's bytes
                    print(f"  {name:<18} {statistics.median(times):6.2f} s (median of {args.repeat}; "
                          f"{min(times):.2f}–{max(times):.2f}; the first visit {first:.2f} s; the server's "
                          f"response {statistics.median(served_s):.2f} s)", flush=True)
                page.goto(served.url)
                page.wait_for_function("window.__shown >= 1")
                delays = []
                for k in range(args.repeat):
                    shown = page.evaluate("window.__shown")
                    written = time.perf_counter()
                    fill_one(engine, args.runs + 1 + k)
                    page.wait_for_function(f"window.__shown > {shown}", timeout=30_000)
                    delays.append(time.perf_counter() - written)
                print(f"  record → tile      {statistics.median(delays):6.2f} s (median of {args.repeat})", flush=True)
        finally:
            served.stop()
            store.close()
            engine.dispose()


def fill_one(engine, run_id: int) -> None:
    """One more unit, written as a station's store writes it (on PostgreSQL: NOTIFY at commit)."""
    from magline.core.record import Outcome, RunRecord
    from magline.core.results.store import SqlStore

    record = RunRecord(serial=f"NEW-{run_id}", part=PARTS[0], station_id=STATIONS[0][0], line=STATIONS[0][1],
                       operator="op", software_version="bench", limit_hash="x")
    record.verdict = Outcome.PASS
    store = SqlStore(engine, "benchmark writer")
    store.begin(record)
    store.finish(record)


if __name__ == "__main__":
    main()
