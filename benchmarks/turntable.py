"""Issue 49's figures: units per hour on the simulated turntable rig against the gimbal and the hand
tumble for the same product, and how many tilts the turntable needs before the calibration is
determined (median, p95).

Every rig calibrates the same simulated PX4 product (``stations/px4-sim.yaml``'s, its compass at the
simulator's default rate, a 2 s boot, real MAVLink on loopback), ``acquisition.stop: determined``:

* turntable: ``stations/turntable-sim.yaml`` (180 °/s, tilts chosen by the coverage) with the simulated
  operator reacting in ``--reaction`` seconds (0.8 by default) and moving the cradle in 0.4 s;
* gimbal: the simulated gimbal's tumble pattern (speed 1);
* hand tumble: the simulated operator's tumble (speed 1), ``motion: operator``.

    python benchmarks/turntable.py [--units 20] [--others 5] [--reaction 0.8] [--seed 49]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from pathlib import Path

import numpy as np
import yaml
from timed_unit import timed_unit

from magline.core.record import Outcome, RunRecord
from magline.sim import create_sim
from magline.sim.gimbal import GimbalSim
from magline.sim.turntable import TurntableSim

REPO = Path(__file__).resolve().parents[1]


def station(folder: Path, board_address: str, motion: dict | None) -> Path:
    cfg = yaml.safe_load((REPO / "stations" / "turntable-sim.yaml").read_text(encoding="utf-8"))
    part = cfg["default_part"]
    cfg["products"][part]["connection"] = board_address.replace("udp:", "udpout://")
    cfg["results"] = {"sink": "sqlite", "path": str(folder / "results.sqlite")}
    if motion is None:
        cfg.pop("motion")
    else:
        cfg["motion"] = motion
    path = folder / "station.yaml"
    path.write_text(yaml.safe_dump(cfg, sort_keys=False), encoding="utf-8")
    return path



def tilts_asked(record: RunRecord) -> int:
    acquire = next((p for p in record.phases if p.name == "acquire"), None)
    return sum(line.startswith("operator: Tilt the cradle:") for line in acquire.log) if acquire else 0


def rig_units(rig: str, units: int, seed: int, reaction_s: float) -> tuple[list[float], list[int], list[str]]:
    walls, tilts, failures = [], [], []
    for n in range(units):
        with tempfile.TemporaryDirectory() as tmp:
            folder = Path(tmp)
            fixture, motion = None, None
            if rig == "turntable":
                fixture = TurntableSim("tcp:127.0.0.1:0", reaction_s=reaction_s).start()
                cfg = yaml.safe_load((REPO / "stations" / "turntable-sim.yaml").read_text(encoding="utf-8"))
                motion = {**cfg["motion"], "options": {**cfg["motion"]["options"], "resource": fixture.visa_resource}}
            elif rig == "gimbal":
                fixture = GimbalSim("tcp:127.0.0.1:0").start()
                motion = {"type": "gimbal", "options": {"resource": fixture.visa_resource, "pattern": "tumble"}}
            options = {"motion_source": fixture.address} if fixture is not None else {"motions": ("tumble",)}
            try:
                with create_sim("px4", "udp:127.0.0.1:0", workdir=folder / "fc", seed=seed + n, **options) as board:
                    record, wall = timed_unit(station(folder, board.address, motion), f"{rig}-{n}")
            finally:
                if fixture is not None:
                    fixture.stop()
        walls.append(wall)
        tilts.append(tilts_asked(record))
        if record.verdict is not Outcome.PASS:
            failures.append(f"{rig} unit {n}: {record.verdict} ({record.cause})")
    return walls, tilts, failures


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--units", type=int, default=20, help="turntable units (the tilt figures)")
    parser.add_argument("--others", type=int, default=5, help="gimbal and hand-tumble units each")
    parser.add_argument("--reaction", type=float, default=0.8, help="the simulated operator's reaction (s)")
    parser.add_argument("--seed", type=int, default=49)
    args = parser.parse_args(argv)
    print(f"units per hour for one simulated PX4 product (median unit, every phase, 2 s boot); "
          f"the turntable's operator reacts in {args.reaction:g} s")
    print(f"   {'rig':<12} {'units':>5} {'median s':>9} {'units/h':>8} {'tilts median':>13} {'tilts p95':>10}")
    for rig, units in (("turntable", args.units), ("gimbal", args.others), ("hand tumble", args.others)):
        walls, tilts, failures = rig_units(rig.split()[0], units, args.seed, args.reaction)
        median = statistics.median(walls)
        tilt_cols = (f"{statistics.median(tilts):>13.0f} {np.percentile(tilts, 95):>10.1f}" if rig == "turntable"
                     else f"{'—':>13} {'—':>10}")
        print(f"   {rig:<12} {units:>5} {median:>9.1f} {3600 / median:>8.0f} {tilt_cols}")
        for failure in failures:
            print(f"      {failure}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
