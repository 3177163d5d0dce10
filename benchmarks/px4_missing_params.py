"""What a PX4 parameter the firmware lacks costs the station (issue 65: the operator's time).

PX4 drops a read of an unknown name without a reply, and an older release lacks names the station asks for
(``CAL_MAGn_xODIAG`` before v1.12, ``CAL_MAGn_ROLL`` before v1.15).  On the simulated PX4 at v1.11.3 this
prints the time of the capability reads the backend makes at connect — the first missing name costs MAVSDK's
resends, after which the firmware's parameter list answers for the rest — and, on links losing frames,
whether the list MAVSDK hands back is whole (the station trusts a name's absence from it).

    python benchmarks/px4_missing_params.py
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from magline.core.dut import DutError
from magline.plugins.px4.link import Px4Link
from magline.sim import SimFaults, create_sim

NAMES = ("CAL_MAG0_XOFF", "CAL_MAG0_XODIAG", "CAL_MAG0_ROLL", "CAL_MAG0_PITCH")


def _link(sim) -> Px4Link:
    _, host, port = sim.address.split(":")
    link = Px4Link(f"udpout://{host}:{port}")
    link.open(10.0)
    return link


def main() -> None:
    workdir = Path(tempfile.mkdtemp())
    print("capability reads at connect, simulated PX4 v1.11.3 (wall time per name)")
    with create_sim("px4", "udp:127.0.0.1:0", workdir=workdir / "old", seed=1, boot_time_s=0.3,
                    firmware="1.11.3").start() as sim:
        link = _link(sim)
        total = 0.0
        for name in NAMES:
            started = time.perf_counter()
            try:
                link.get(name, False)
                said = "read"
            except DutError as exc:
                said = type(exc).__name__
            took = time.perf_counter() - started
            total += took
            print(f"  {name:<18} {said:<12} {took:6.2f} s")
        print(f"  {'all four':<18} {'':<12} {total:6.2f} s   (lists asked: {sim.param_lists})")
        link.close()
    print("the parameter list MAVSDK hands back, on a link losing frames")
    for percent in (0.0, 10.0, 30.0):
        with create_sim("px4", "udp:127.0.0.1:0", workdir=workdir / f"loss{percent:g}", seed=1, boot_time_s=0.3,
                        faults=SimFaults(drop_percent=percent)).start() as sim:
            link = _link(sim)
            started = time.perf_counter()
            names = link.listed_names() or frozenset()
            took = time.perf_counter() - started
            print(f"  {percent:4.0f} % lost: {len(names)} of {len(sim.table.values)} names in {took:5.2f} s")
            link.close()


if __name__ == "__main__":
    main()
