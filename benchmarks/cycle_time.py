"""Cycle time per unit on every backend, ``acquisition.stop: samples`` against ``stop: determined``
(issue 27): units per hour and the median time of each phase, at the shipped station files with the
simulators' shipped defaults (boot time, sensor rate), real MAVLink on loopback.  Figures only.

* demo: ``stations/demo.yaml``, the in-process mock (real time), as the README's first command;
* px4 / ardupilot: ``stations/px4-sim.yaml`` / ``ardupilot-sim.yaml`` against ``magline sim``;
* four slots: ``stations/slots-sim.yaml`` (two PX4, two ArduPilot boards on one gimbal), against the
  same four boards calibrated one slot at a time.

Goals: ArduPilot unit ≤ 25 s, PX4 unit ≤ 15 s waiting for the drift test and ≤ 9 s warm, demo unit ≤ 4 s, four
slots ≥ 3.5 × one.
Each is run ``stop: samples``, ``stop: determined`` and ``warm`` (determined with
``wait_for_drift_test: false``: what a line of units warm before calibration may choose).  A determined
stop is measured on a line that has learnt its time skew (a new line's first units, which tumble
until the skew is told from a turned compass, are printed apart).

    python benchmarks/cycle_time.py [--units 3] [--loads 1] [--only demo px4 ardupilot slots]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from magline.core.mounting.line_skew import LEARN_MIN_UNITS
from magline.core.plugins import load_plugins
from magline.core.record import RunRecord
from magline.core.sequencer import Sequencer
from magline.core.sequencer.slots import SlotRunner
from magline.core.station import load_station

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).parent))
from slots import BOARDS, start, start_fixture, station_file  # noqa: E402  (the slots benchmark's four-board fixture)

# each mode's acquisition settings; "warm": determined, without waiting for the drift test (a line whose
# units are warm before calibration, issue 28)
STOPS = {"samples": {"stop": "samples"}, "determined": {"stop": "determined"},
         "warm": {"stop": "determined", "wait_for_drift_test": False}}
# per mode: a PX4 unit that waits for the drift test tumbles until it is told, a warm one does not
GOALS_S = {"determined": {"demo": 4.0, "px4": 15.0, "ardupilot": 25.0},
           "warm": {"demo": 4.0, "px4": 9.0, "ardupilot": 25.0}}
# units a new line runs before it has learnt its time skew: the passing units it learns from, and one
LEARNING_UNITS = LEARN_MIN_UNITS + 1
SLOT_SPEEDUP_GOAL = 3.5


@dataclass
class Figures:
    walls: list[float] = field(default_factory=list)  # per unit, including the restore / close after phases
    phases: dict[str, list[float]] = field(default_factory=dict)
    tumbles: list[float] = field(default_factory=list)  # the accepted attempt's tumbling time
    readings: list[int] = field(default_factory=list)
    verdicts: list[str] = field(default_factory=list)

    def add(self, record: RunRecord, wall: float) -> None:
        self.walls.append(wall)
        self.verdicts.append(f"{record.verdict}" + ("" if str(record.verdict) == "pass" else f" ({record.cause})"))
        for p in record.phases:
            self.phases.setdefault(p.name, []).append(p.duration_s)
        accepted = [a for a in record.attempts if a.accepted] or record.attempts[-1:]
        if accepted:
            self.tumbles.append(accepted[0].tumble_s or 0.0)
            self.readings.append(accepted[0].samples)

    def line(self, name: str, stop: str) -> str:
        wall = statistics.median(self.walls)
        phases = "  ".join(f"{n} {statistics.median(v):.1f}" for n, v in self.phases.items()
                           if statistics.median(v) >= 0.05)
        passed = sum(v == "pass" for v in self.verdicts)
        return (f"{name:<10} {stop:<10} {passed}/{len(self.walls)} pass  unit {wall:5.1f} s  "
                f"{3600 / wall:6.0f} units/h  "
                f"tumble {statistics.median(self.tumbles):4.1f} s ({statistics.median(self.readings):.0f} readings)  "
                f"phases: {phases}")


def write(cfg: dict, path: Path, stop: str) -> Path:
    cfg["acquisition"].update(STOPS[stop])
    cfg.setdefault("review", {})["enabled"] = False
    path.write_text(yaml.safe_dump(cfg, sort_keys=False), encoding="utf-8")
    return path


def run_units(path: Path, units: int, label: str, learning: Figures | None = None) -> Figures:
    """``units`` measured; with ``learning``, first the units a new line runs before it knows its time
    skew (core/mounting/line_skew.py), recorded there: a line's steady state is what it runs all day."""
    figures = Figures()
    seq = Sequencer(load_station(path), load_plugins(), path.parent)
    try:
        for i in range(-LEARNING_UNITS if learning is not None else 0, units):
            started = time.perf_counter()
            record = seq.run_unit(f"{label}-{i}")
            (figures if i >= 0 else learning).add(record, time.perf_counter() - started)
    finally:
        seq.close()
    return figures


def demo(work: Path, stop: str, units: int) -> Figures:
    cfg = yaml.safe_load((REPO / "stations" / "demo.yaml").read_text(encoding="utf-8"))
    cfg["results"]["path"] = str(work / f"demo-{stop}.sqlite")
    return run_units(write(cfg, work / f"demo-{stop}.yaml", stop), units, f"DEMO-{stop}")


def simulated(work: Path, flavour: str, stop: str, units: int, learning: Figures | None = None) -> Figures:
    listen = "udp:127.0.0.1:0" if flavour == "px4" else "tcp:127.0.0.1:0"
    proc, address = start([flavour, "--listen", listen, "--workdir", str(work / f"fc-{flavour}-{stop}")])
    try:
        cfg = yaml.safe_load((REPO / "stations" / f"{flavour}-sim.yaml").read_text(encoding="utf-8"))
        _, host, port = address.split(":")
        part = cfg["default_part"]
        cfg["products"][part]["connection"] = f"udpout://{host}:{port}" if flavour == "px4" else f"tcp:{host}:{port}"
        cfg["results"]["path"] = str(work / f"{flavour}-{stop}.sqlite")
        return run_units(write(cfg, work / f"{flavour}-{stop}.yaml", stop), units, f"{flavour.upper()}-{stop}",
                         learning)
    finally:
        proc.terminate()
        proc.wait(10)


def slots(work: Path, stop: str, loads: int) -> tuple[float, float, list[RunRecord]]:
    """Seconds for the four boards one slot at a time, then four together; the four-slot records."""
    procs = []
    try:
        gimbal, addresses = start_fixture(work / stop, procs)

        def station(chosen: list[str]) -> Path:  # the shipped slot station, stopping as ``stop`` says
            return station_file(work, addresses, gimbal, chosen, acquisition=STOPS[stop], tag=f"-{stop}")

        def run(path: Path, loads_: list[dict[str, str]]) -> tuple[float, list[RunRecord]]:
            seq = Sequencer(load_station(path), load_plugins(), path.parent)
            started = time.perf_counter()
            try:
                records = [r for load in loads_ for r in SlotRunner(seq).run(load)]
            finally:
                seq.close()
            return time.perf_counter() - started, records

        one_s = sum(run(station([s]), [{s: f"ONE-{s}-{i}-{stop}"} for i in range(loads)])[0] for s in BOARDS)
        four_s, records = run(station(list(BOARDS)), [{s: f"FOUR-{s}-{i}-{stop}" for s in BOARDS}
                                                      for i in range(loads)])
        return one_s, four_s, records
    finally:
        for proc in procs:
            proc.terminate()
            proc.wait(10)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--units", type=int, default=3, help="units per backend and stop mode")
    parser.add_argument("--loads", type=int, default=1, help="fixture loads of four units (slots)")
    parser.add_argument("--only", nargs="+", choices=["demo", "px4", "ardupilot", "slots"],
                        default=["demo", "px4", "ardupilot", "slots"], help="the configurations to run")
    args = parser.parse_args()
    medians: dict[tuple[str, str], float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for name in [n for n in ("demo", "px4", "ardupilot") if n in args.only]:
            for stop in STOPS:
                learning = Figures() if name != "demo" and stop != "samples" else None
                figures = demo(work, stop, args.units) if name == "demo" else simulated(work, name, stop, args.units,
                                                                                        learning)
                medians[name, stop] = statistics.median(figures.walls)
                print(figures.line(name, stop), flush=True)
                if learning is not None and learning.walls:
                    print(f"{'':<21} a new line's first {len(learning.walls)} units (learning its time skew): "
                          f"unit {statistics.median(learning.walls):.1f} s, tumble "
                          f"{statistics.median(learning.tumbles):.1f} s", flush=True)
                for verdict in figures.verdicts:
                    if verdict != "pass":
                        print(f"{'':<21} not passed: {verdict}")
        speedups = {}
        if "slots" in args.only:
            for stop in STOPS:
                one_s, four_s, records = slots(work, stop, args.loads)
                units = 4 * args.loads
                speedups[stop] = one_s / four_s
                passed = sum(str(r.verdict) == "pass" for r in records)
                print(f"four slots {stop:<10} {passed}/{len(records)} pass  one slot {units / one_s * 3600:5.0f} "
                      f"units/h, four slots {units / four_s * 3600:5.0f} units/h: {one_s / four_s:.1f}×", flush=True)
    for mode in ("determined", "warm"):
        print(f"goals ({mode}, shipped station files):")
        for name, goal in GOALS_S[mode].items():
            if (name, mode) not in medians:
                continue
            got = medians[name, mode]
            print(f"  {name:<10} unit ≤ {goal:g} s: {got:.1f} s {'met' if got <= goal else 'NOT MET'}")
        if mode in speedups:
            got = speedups[mode]
            verdict = "met" if got >= SLOT_SPEEDUP_GOAL else "NOT MET"
            print(f"  four slots ≥ {SLOT_SPEEDUP_GOAL}× one slot: {got:.1f}× {verdict}")


if __name__ == "__main__":
    main()
