"""Station time per unit on the simulated PX4, ArduPilot and INAV: each phase, and the overhead beyond
acquisition (connect + prepare, write + forced save, power cycle + read-back, record, and the
restore / close after the phases) measured as the unit's wall time minus its acquisition.

Conditions of the issues: simulated boot time 2 s, 600 samples at 50 Hz (12 s of tumbling), a real
MAVLink link on loopback (UDP for PX4 through MAVSDK, TCP for ArduPilot through pymavlink), INAV's MSP over
TCP.
Target: overhead ≤ 8 s, of which the simulated boot is 2 s.  Figures only, not a test.

    python benchmarks/station_overhead.py [--units 3] [--boot-time 2]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import yaml

from magline.core.plugins import load_plugins
from magline.core.sequencer import Sequencer
from magline.core.station import load_station
from magline.sim import create_sim

REPO = Path(__file__).resolve().parents[1]
FLAVOURS = {"px4": ("px4-sim.yaml", "udp", "udpout://{host}:{port}"),
            "ardupilot": ("ardupilot-sim.yaml", "tcp", "tcp:{host}:{port}"),
            "inav": ("inav-sim.yaml", "tcp", "tcp:{host}:{port}")}
OVERHEAD_TARGET_S = 8.0
OWN_GOAL_S = 2.0  # the station's own time beyond the tumble and the firmware's boot


def station_file(flavour: str, address: str, workdir: Path) -> Path:
    example, _, url = FLAVOURS[flavour]
    cfg = yaml.safe_load((REPO / "stations" / example).read_text(encoding="utf-8"))
    _, host, port = address.split(":")
    part = cfg["default_part"]
    cfg["products"][part]["connection"] = url.format(host=host, port=port)
    cfg["acquisition"].update({"samples": 600, "rate_hz": 50.0})
    cfg["results"]["path"] = str(workdir / "results.sqlite")
    path = workdir / "station.yaml"
    path.write_text(yaml.safe_dump(cfg, sort_keys=False), encoding="utf-8")
    return path


def bench(flavour: str, units: int, boot_time: float) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        scheme = FLAVOURS[flavour][1]
        with create_sim(flavour, f"{scheme}:127.0.0.1:0", workdir=work / "fc", boot_time_s=boot_time, seed=3) as sim:
            seq = Sequencer(load_station(station_file(flavour, sim.address, work)), load_plugins(), work)
            rows = []
            for i in range(units):
                start = time.perf_counter()
                record = seq.run_unit(f"BENCH-{flavour}-{i}")
                wall = time.perf_counter() - start  # includes restore / close after the phases
                phases = {p.name: p.duration_s for p in record.phases}
                figures = record.persistence.get("figures", {})
                rows.append((record.verdict.value, phases, figures, wall))
            seq.close()
    names = ["connect", "acquire", "fit", "validate", "persist", "verify", "record"]
    print(f"\n{flavour}: {units} unit(s), boot time {boot_time:g} s, 600 samples at 50 Hz")
    print("  verdict  " + "  ".join(f"{n:>8}" for n in names) + "  cleanup  overhead  reboot→link")
    overheads, own = [], []
    for verdict, phases, figures, wall in rows:
        overhead = wall - phases.get("acquire", 0.0)
        cleanup = wall - sum(phases.values())
        overheads.append(overhead)
        own.append(overhead - figures.get("time_to_heartbeat_s", 0.0))
        print(f"  {verdict:7}  " + "  ".join(f"{phases.get(n, 0.0):8.2f}" for n in names)
              + f"  {cleanup:7.2f}  {overhead:8.2f}  {figures.get('time_to_heartbeat_s', float('nan')):11.2f}")
    worst = max(overheads)
    print(f"  overhead median {statistics.median(overheads):.2f} s, worst {worst:.2f} s "
          f"(target ≤ {OVERHEAD_TARGET_S:g} s: {'met' if worst <= OVERHEAD_TARGET_S else 'NOT met'})")
    print(f"  the station's own, beyond the firmware's reboot and boot (reboot→link): median "
          f"{statistics.median(own):.2f} s, worst {max(own):.2f} s (goal ≤ {OWN_GOAL_S:g} s: "
          f"{'met' if max(own) <= OWN_GOAL_S else 'NOT met'})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--units", type=int, default=3)
    parser.add_argument("--boot-time", type=float, default=2.0)
    parser.add_argument("--flavour", choices=[*FLAVOURS, "all"], default="all")
    args = parser.parse_args()
    for flavour in FLAVOURS if args.flavour == "all" else [args.flavour]:
        bench(flavour, args.units, args.boot_time)


if __name__ == "__main__":
    main()
