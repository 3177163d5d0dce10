"""Parallel slots: units per hour with one slot against four, and the station's CPU per slot while
the units are sampled (figures printed, never asserted).

Conditions of the issue: simulated flight controllers with a 2 s boot, 600 samples at 50 Hz
(the sensors publish 50 distinct readings/s), real MAVLink on loopback (PX4 over UDP through
MAVSDK, ArduPilot over TCP through pymavlink).  The gimbal and the four boards run as separate
``magline sim`` processes mounted on the gimbal, so the station process is measured alone (its
CPU includes the mavsdk_server processes it starts, one per PX4 unit).

* 1 slot: the four boards calibrated one after the other (the station as it was);
* 4 slots: the four together on the shared gimbal.

    python benchmarks/slots.py [--loads 1] [--boot-time 2]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml
from proc_stat import TICK, process_stats

from magline.core.plugins import hookimpl, load_plugins
from magline.core.sequencer import Sequencer
from magline.core.sequencer.slots import SlotRunner
from magline.core.station import load_station

REPO = Path(__file__).resolve().parents[1]
BOARDS = {"A": "px4", "B": "px4", "C": "ardupilot", "D": "ardupilot"}


def start(args: list[str]) -> tuple[subprocess.Popen, str]:
    """A ``magline sim`` process and the address it announces on its first line."""
    proc = subprocess.Popen([sys.executable, "-c", "from magline.core.cli import main; raise SystemExit(main())",
                             "sim", *args], stdout=subprocess.PIPE, text=True)
    first = proc.stdout.readline().strip()
    if not first.startswith("listening on "):
        raise RuntimeError(f"magline sim {' '.join(args)} did not start: {first!r}")
    return proc, first.removeprefix("listening on ")


def start_fixture(work: Path, procs: list[subprocess.Popen],
                  extra: list[str] | None = None) -> tuple[str, dict[str, str]]:
    """The gimbal and the four boards mounted on it, each a ``magline sim`` process (added to ``procs``,
    which the caller stops), with ``extra`` options for every board; the gimbal's and each slot's address."""
    gimbal_proc, gimbal = start(["gimbal", "--listen", "tcp:127.0.0.1:0"])
    procs.append(gimbal_proc)
    addresses = {}
    for slot, flavour in BOARDS.items():
        listen = "udp:127.0.0.1:0" if flavour == "px4" else "tcp:127.0.0.1:0"
        proc, addresses[slot] = start([flavour, "--listen", listen, "--gimbal", gimbal, "--workdir",
                                       str(work / f"fc-{slot}"), *(extra or []), "--seed", str(ord(slot))])
        procs.append(proc)
    return gimbal, addresses


def children_cpu_s() -> float:
    """User + system CPU of this process's live children (mavsdk_server), from /proc."""
    me = os.getpid()
    return sum(int(f[11]) + int(f[12]) for _, parent, f in process_stats() if parent == me) / TICK


class AcquisitionCpu:
    """Station CPU (all threads + mavsdk_server children) between each round's start and stop."""

    def __init__(self) -> None:
        self.windows: list[tuple[int, float, float]] = []  # (slots, cpu s, wall s)
        self._at: tuple[float, float] | None = None

    def now(self) -> tuple[float, float]:
        return time.process_time() + children_cpu_s(), time.perf_counter()

    @hookimpl
    def magline_motion_started(self, round, slots, motion):
        self._at = self.now()

    @hookimpl
    def magline_motion_stopped(self, round, slots, motion):
        cpu, wall = self.now()
        self.windows.append((len(slots), cpu - self._at[0], wall - self._at[1]))


def station_file(work: Path, addresses: dict[str, str], gimbal: str, slots: list[str],
                 acquisition: dict | None = None, tag: str = "") -> Path:
    """``stations/slots-sim.yaml`` for the chosen slots of the fixture, its acquisition changed by
    ``acquisition`` (this benchmark's fixed count by default; ``{}``: as shipped), results in ``work``."""
    cfg = yaml.safe_load((REPO / "stations" / "slots-sim.yaml").read_text(encoding="utf-8"))
    cfg["slots"] = [s for s in cfg["slots"] if s["id"] in slots]
    for slot in cfg["slots"]:
        _, host, port = addresses[slot["id"]].split(":")
        slot["connection"] = f"udpout://{host}:{port}" if BOARDS[slot["id"]] == "px4" else f"tcp:{host}:{port}"
    _, host, port = gimbal.split(":")
    cfg["motion"]["options"]["resource"] = f"TCPIP0::{host}::{port}::SOCKET"
    cfg["acquisition"].update({"samples": 600, "rate_hz": 50.0} if acquisition is None else acquisition)
    cfg["results"]["path"] = str(work / f"results{tag}.sqlite")
    cfg["review"] = {"enabled": False}
    path = work / f"station-{''.join(slots)}{tag}.yaml"
    path.write_text(yaml.safe_dump(cfg, sort_keys=False), encoding="utf-8")
    return path


def run_loads(path: Path, loads: list[dict[str, str]], cpu: AcquisitionCpu) -> tuple[float, list]:
    seq = Sequencer(load_station(path), load_plugins(extra=[cpu]), path.parent)
    runner = SlotRunner(seq)
    records = []
    started = time.perf_counter()
    try:
        for load in loads:
            records += runner.run(load)
    finally:
        seq.close()
    return time.perf_counter() - started, records


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--loads", type=int, default=1, help="fixture loads of four units per configuration")
    parser.add_argument("--boot-time", type=float, default=2.0)
    args = parser.parse_args()
    procs = []
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        try:
            gimbal, addresses = start_fixture(work, procs, ["--boot-time", str(args.boot_time), "--mag-rate", "50"])
            serial = iter(range(1_000_000))
            one_cpu, four_cpu = AcquisitionCpu(), AcquisitionCpu()
            one_s, one_records = 0.0, []
            for slot in BOARDS:  # one slot at a time: the four boards one after the other
                path = station_file(work, addresses, gimbal, [slot])
                took, records = run_loads(path, [{slot: f"ONE-{next(serial)}"} for _ in range(args.loads)], one_cpu)
                one_s += took
                one_records += records
            path = station_file(work, addresses, gimbal, list(BOARDS))
            four_s, four_records = run_loads(
                path, [{slot: f"FOUR-{next(serial)}" for slot in BOARDS} for _ in range(args.loads)], four_cpu)
        finally:
            for proc in procs:
                proc.terminate()
                proc.wait(10)
    units = 4 * args.loads
    for name, records in (("1 slot", one_records), ("4 slots", four_records)):
        bad = [(r.slot, r.verdict, r.cause) for r in records if str(r.verdict) != "pass"]
        note = f"; not passed: {bad}" if bad else ""
        print(f"{name}: {len(records)} units, {len(records) - len(bad)} passed{note}")
    print(f"1 slot : {units} units in {one_s:.1f} s = {units / one_s * 3600:.0f} units/h")
    print(f"4 slots: {units} units in {four_s:.1f} s = {units / four_s * 3600:.0f} units/h")
    for name, cpu in (("1 slot", one_cpu), ("4 slots", four_cpu)):
        slots = sum(n for n, _, _ in cpu.windows)
        cpu_s, wall_s = sum(c for _, c, _ in cpu.windows), sum(w for _, _, w in cpu.windows)
        per_slot = cpu_s / wall_s / (slots / len(cpu.windows)) * 100
        print(f"station CPU while sampling, {name}: {cpu_s / wall_s * 100:.0f} % of one core, "
              f"{per_slot:.1f} % per slot at 50 Hz (2 cores = 200 %)")
    print(f"speed-up {one_s / four_s:.1f}× (goal ≥ 3.5×)")
    # where the time goes: each phase per slot (a round waits for every slot's connect before the gimbal moves)
    names = ["connect", "acquire", "fit", "validate", "persist", "verify", "record"]
    print("phase seconds per unit   " + "  ".join(f"{n:>8}" for n in names))
    for name, records in (("1 slot", one_records), ("4 slots", four_records)):
        for r in records:
            took = {p.name: p.duration_s for p in r.phases}
            print(f"  {name:7} {r.slot or '':2} {BOARDS.get(r.slot or '', ''):9}  "
                  + "  ".join(f"{took.get(n, 0.0):8.2f}" for n in names))


if __name__ == "__main__":
    main()
