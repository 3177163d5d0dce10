"""Station-screen figures (printed, never asserted), on the demo station in real time (600 samples
at 200 samples/s, the operator's spin then the tumble):

1. latency from a sample reaching the sequencer to the coverage sphere redrawn in the page
   (Debian Chromium through playwright; median and p95; goal p95 ≤ 150 ms);
2. the screen's cost to the unit: wall time of a unit with the screen and a page watching,
   against the same station run console-only (goal ≤ 2 %).

    python benchmarks/screen.py [--units 3]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))

from browser import chromium, open_page  # noqa: E402
from test_station_screen import Served, free_port  # noqa: E402

from magline.core.plugins import load_plugins  # noqa: E402
from magline.core.screen.serve import build  # noqa: E402
from magline.core.sequencer import Sequencer  # noqa: E402
from magline.core.station import load_station  # noqa: E402


def station_file(folder: Path) -> Path:
    cfg = yaml.safe_load((REPO / "stations" / "demo.yaml").read_text(encoding="utf-8"))
    cfg["products"]["MOCK-100"]["options"].update({"realtime": True, "seed": 3})
    cfg["acquisition"]["retry_delay_s"] = 0.0
    path = folder / "screen-bench.yaml"
    path.write_text(yaml.safe_dump(cfg, sort_keys=False, allow_unicode=True), encoding="utf-8")
    return path


def console_only(path: Path, units: int) -> list[float]:
    seq = Sequencer(load_station(path), load_plugins(), path.parent)
    times = []
    try:
        for i in range(units):
            t = time.perf_counter()
            seq.run_unit(f"CON-{i}")
            times.append(time.perf_counter() - t)
    finally:
        seq.close()
    return times


def with_screen(path: Path, units: int) -> tuple[list[float], list[float]]:
    app, runner = build(load_station(path), path.parent, load_plugins())
    served = Served(app, free_port())
    times: list[float] = []
    latencies: list[float] = []
    try:
        with chromium() as browser:
            page = open_page(browser, served.url).page
            page.wait_for_selector("#station-name:has-text('demo-01')")
            for i in range(units):
                page.evaluate("window.__latencies = []")
                t = time.perf_counter()
                runner.start(f"SCR-{i}", None)
                runner.wait()
                times.append(time.perf_counter() - t)
                page.wait_for_selector("#verdict:not([hidden])")
                latencies += page.evaluate("window.__latencies")
    finally:
        served.stop()
        runner.close()
    return times, latencies


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--units", type=int, default=3)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        path = station_file(Path(tmp))
        plain = console_only(path, args.units)
        screened, latencies = with_screen(path, args.units)
    lat = np.array(latencies)
    print(f"1. sample → sphere redrawn: {lat.size} updates, median {np.median(lat):.0f} ms, "
          f"p95 {np.percentile(lat, 95):.0f} ms (goal p95 ≤ 150 ms)")
    a, b = statistics.median(plain), statistics.median(screened)
    print(f"2. unit wall time: console-only {a:.2f} s, with the screen {b:.2f} s: {100 * (b - a) / a:+.1f} % "
          "(goal ≤ 2 %)")


if __name__ == "__main__":
    main()
