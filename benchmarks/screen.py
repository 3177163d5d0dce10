"""Station-screen figures (printed, never asserted), on the demo station in real time (600 samples
at 200 samples/s, the operator's spin then the tumble):

1. latency from a sample reaching the sequencer to the coverage sphere redrawn in the page
   (Debian Chromium through playwright; median and p95; goal p95 ≤ 150 ms);
2. the screen's cost to the unit: wall time of a unit with the screen and a page watching,
   against the same station run console-only, units alternating between the two after one
   warm-up unit each (goal ≤ 2 %).  The mock's readings are paced in real time, so the figure is
   the screen's cost on top of the fixed acquisition time; the CPU time of the process is printed
   too, since that is what the screen takes from the sequencer on a loaded line PC.

    python benchmarks/screen.py [--units 8]
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

from magline.core.operator_ui.screen.serve import build  # noqa: E402
from magline.core.plugins import load_plugins  # noqa: E402
from magline.core.sequencer import Sequencer  # noqa: E402
from magline.core.station import load_station  # noqa: E402


def station_file(folder: Path) -> Path:
    cfg = yaml.safe_load((REPO / "stations" / "demo.yaml").read_text(encoding="utf-8"))
    cfg["products"]["MOCK-100"]["options"].update({"realtime": True, "seed": 3})
    cfg["acquisition"]["retry_delay_s"] = 0.0
    path = folder / "screen-bench.yaml"
    path.write_text(yaml.safe_dump(cfg, sort_keys=False, allow_unicode=True), encoding="utf-8")
    return path


class ConsoleOnly:
    def __init__(self, path: Path) -> None:
        self.seq = Sequencer(load_station(path), load_plugins(), path.parent)

    def unit(self, serial: str) -> None:
        self.seq.run_unit(serial)

    def close(self) -> None:
        self.seq.close()


class WithScreen:
    """The screen served on a real socket with Chromium watching, units started as the page would."""

    def __init__(self, path: Path, browser) -> None:
        self.app, self.runner = build(load_station(path), path.parent, load_plugins())
        self.served = Served(self.app, free_port())
        self.page = open_page(browser, self.served.url).page
        self.page.wait_for_selector("#station-name:has-text('demo-01')")
        self.latencies: list[dict] = []

    def unit(self, serial: str) -> None:
        self.page.evaluate("window.__latencies = []")
        self.runner.start(serial, None)
        self.runner.wait()
        self.page.wait_for_selector("#verdict:not([hidden])")
        self.latencies += self.page.evaluate("window.__latencies")

    def close(self) -> None:
        self.served.stop()
        self.runner.close()


def timed(station, serial: str) -> tuple[float, float]:
    wall, cpu = time.perf_counter(), time.process_time()
    station.unit(serial)
    return time.perf_counter() - wall, time.process_time() - cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--units", type=int, default=8)
    args = parser.parse_args()
    plain: list[tuple[float, float]] = []
    screened: list[tuple[float, float]] = []
    with tempfile.TemporaryDirectory() as tmp, chromium() as browser:
        path = station_file(Path(tmp))
        console, screen = ConsoleOnly(path), WithScreen(path, browser)
        try:
            console.unit("WARM-C")
            screen.unit("WARM-S")
            screen.latencies.clear()
            for i in range(args.units):
                plain.append(timed(console, f"CON-{i}"))
                screened.append(timed(screen, f"SCR-{i}"))
        finally:
            console.close()
            screen.close()
    every = np.array([x["ms"] for x in screen.latencies])
    redrawn = np.array([x["ms"] for x in screen.latencies if x["sphere"]])
    print(f"1. sample → page painted: {every.size} updates shown, median {np.median(every):.0f} ms, "
          f"p95 {np.percentile(every, 95):.0f} ms; those that recoloured the sphere: {redrawn.size}, "
          f"median {np.median(redrawn):.0f} ms, p95 {np.percentile(redrawn, 95):.0f} ms (goal p95 ≤ 150 ms)")
    a, b = (statistics.median(w for w, _ in plain), statistics.median(w for w, _ in screened))
    ca, cb = (statistics.median(c for _, c in plain), statistics.median(c for _, c in screened))
    print(f"   ({len(plain)} units each) process CPU per unit: console-only {ca:.2f} s, with the screen {cb:.2f} s")
    print(f"2. unit wall time, median: console-only {a:.2f} s, with the screen {b:.2f} s: "
          f"{100 * (b - a) / a:+.1f} % (goal ≤ 2 %)")

if __name__ == "__main__":
    main()
