"""Simulated flight controllers that speak real MAVLink on a real socket: ``magline sim px4|ardupilot``.

The px4 and ardupilot backends are tested against these, never against mocks of their own code.
Start one from Python with port 0 and read the chosen address::

    with create_sim("px4", "udp:127.0.0.1:0", workdir=tmp) as sim:
        connect_to(sim.address)
"""

from __future__ import annotations

from typing import Any

from magline.sim.ardupilot import ArduPilotSim
from magline.sim.faults import SimFaults
from magline.sim.magnetometers import SimMagnetometer, device_id
from magline.sim.px4 import Px4Sim
from magline.sim.vehicle import Power, SimulatedAutopilot

FLAVOURS: dict[str, type[SimulatedAutopilot]] = {"px4": Px4Sim, "ardupilot": ArduPilotSim}


def create_sim(flavour: str, listen: str | None = None, **options: Any) -> SimulatedAutopilot:
    """A simulator of ``flavour`` (not started); ``listen`` defaults to the flavour's example address."""
    try:
        cls = FLAVOURS[flavour]
    except KeyError:
        raise ValueError(f"unknown simulator {flavour!r}; choose from {', '.join(FLAVOURS)}") from None
    return cls(listen, **options)


__all__ = ["FLAVOURS", "ArduPilotSim", "Power", "Px4Sim", "SimFaults", "SimMagnetometer", "SimulatedAutopilot",
           "create_sim", "device_id"]
