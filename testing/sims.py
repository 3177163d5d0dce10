"""Simulated flight controllers for tests: their firmware's own protocol (MAVLink, INAV's MSP) on a free
loopback port, short boots.

Why here: a DUT plugin for another autopilot, a power control or a field source is best tested
against a vehicle that speaks the protocol, not against a mock of one's own code.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

FAST = {"boot_time_s": 0.3, "mag_rate_hz": 100.0, "speed": 5.0}  # what magline's own backend tests use
# A board the station polls (INAV's MSP) is read as often as the station's loop runs, not on the board's own
# clock as a MAVLink stream is: on a loaded machine the polls thin out, and a tumble five times a hand's pace
# (its field spinning 1,600°/s) is then undersampled. At twice a hand's pace a good unit holds at 20 Hz, 2.5
# times below the 50 Hz the station asks (at 12 Hz it passed once and failed once; at five times it failed at
# 20 Hz): ``benchmarks/polled_pace.py`` prints the margins.
POLLED_SPEED = 2.0


@dataclass
class SimulatedVehicle:
    sim: Any  # magline.sim.SimulatedAutopilot: faults, parameters, storage, magnetometers
    connection: str  # what a station's ``connection`` says to reach it

    @property
    def address(self) -> str:
        return self.sim.address


@contextmanager
def _vehicle(flavour: str, listen: str, scheme: str, workdir: str | Path, **options: Any) -> Iterator[SimulatedVehicle]:
    from magline.sim import create_sim

    sim = create_sim(flavour, listen, workdir=Path(workdir), **{**FAST, **options}).start()
    try:
        _, host, port = sim.address.split(":")
        yield SimulatedVehicle(sim, scheme.format(host=host, port=port))
    finally:
        sim.stop()


def px4_sim(workdir: str | Path, **options: Any) -> Any:
    """A simulated PX4 on UDP (``with px4_sim(tmp_path) as fc: … fc.connection``); ``options`` as
    ``magline sim px4`` takes them (``mag_count``, ``faults``, ``shell``, ``motions`` …)."""
    return _vehicle("px4", "udp:127.0.0.1:0", "udpout://{host}:{port}", workdir, **options)


def ardupilot_sim(workdir: str | Path, **options: Any) -> Any:
    """A simulated ArduPilot on TCP (``with ardupilot_sim(tmp_path) as fc: … fc.connection``)."""
    return _vehicle("ardupilot", "tcp:127.0.0.1:0", "tcp:{host}:{port}", workdir, **options)


def inav_sim(workdir: str | Path, **options: Any) -> Any:
    """A simulated INAV speaking MSP on TCP (``with inav_sim(tmp_path) as fc: … fc.connection``); ``options``
    as ``magline sim inav`` takes them (``faults``, ``magnetometers``, ``counts_per_gauss`` …)."""
    return _vehicle("inav", "tcp:127.0.0.1:0", "tcp:{host}:{port}", workdir, **{"speed": POLLED_SPEED, **options})
