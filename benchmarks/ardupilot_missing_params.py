"""What an ArduPilot parameter the firmware lacks costs the station, and what a lossy link costs the proof.

ArduPilot drops a read of an unknown name without a reply; the backend tells such a name by reads sent after
it and answered (``ArduPilotLink.get``).  On the simulated ArduPilot this prints the time of a read of a
name the firmware has, of one it lacks (``COMPASS_MOT_X``, a build without compass-motor compensation) and,
on links losing each frame the board sends with some probability, how many reads of names the firmware has
were wrongly told unknown (the proof's false alarms), answered, or left unanswered.

    python benchmarks/ardupilot_missing_params.py [--reads 300]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections import Counter
from pathlib import Path

from magline.core.dut import UnansweredRequest
from magline.plugins.ardupilot.link import ArduPilotLink, NotKnown
from magline.sim import SimFaults, create_sim

PRESENT = ("COMPASS_DEV_ID", "COMPASS_OFS_X", "COMPASS_DIA_Y", "COMPASS_ODI_Z", "COMPASS_EXTERNAL", "COMPASS_ORIENT")


def _read(link: ArduPilotLink, name: str) -> str:
    try:
        link.get(name)
        return "read"
    except NotKnown:
        return "told unknown"
    except UnansweredRequest:
        return "unanswered"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reads", type=int, default=300, help="reads of present names per loss rate")
    args = parser.parse_args()
    workdir = Path(tempfile.mkdtemp())
    print("one read each, simulated ArduPilot without COMPASS_MOT (wall time)")
    faults = SimFaults(unknown_params=["COMPASS_MOT_X", "COMPASS_MOT_Y", "COMPASS_MOT_Z"])
    with create_sim("ardupilot", "tcp:127.0.0.1:0", workdir=workdir / "nomot", seed=1, boot_time_s=0.3,
                    faults=faults).start() as sim:
        link = ArduPilotLink(sim.address)
        link.open(10.0)
        for name in ("COMPASS_DEV_ID", "COMPASS_MOT_X", "COMPASS_OFS_X"):
            started = time.perf_counter()
            said = _read(link, name)
            print(f"  {name:<16} {said:<13} {time.perf_counter() - started:6.3f} s   "
                  f"(reads of it: {sim.param_reads[name]})")
        link.close()
    print(f"{args.reads} reads of names the firmware has, on a link losing the board's frames")
    for percent in (2.0, 10.0, 30.0):
        with create_sim("ardupilot", "tcp:127.0.0.1:0", workdir=workdir / f"loss{percent:g}", seed=2,
                        boot_time_s=0.3, faults=SimFaults(drop_percent=percent)).start() as sim:
            link = ArduPilotLink(sim.address)
            link.open(10.0)
            outcomes: Counter[str] = Counter()
            started = time.perf_counter()
            for i in range(args.reads):
                outcomes[_read(link, PRESENT[i % len(PRESENT)])] += 1
            took = time.perf_counter() - started
            link.close()
        print(f"  {percent:4.0f} % lost: " + ", ".join(f"{k} {v}" for k, v in sorted(outcomes.items()))
              + f"   in {took:6.1f} s")


if __name__ == "__main__":
    main()
