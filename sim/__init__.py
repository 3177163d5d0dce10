"""Simulated flight controllers that speak their firmware's own protocol on a real socket: ``magline sim
px4|ardupilot`` (MAVLink), ``magline sim inav`` (MSP).

The px4 and ardupilot backends are tested against these, never against mocks of their own code.
Start one from Python with port 0 and read the chosen address::

    with create_sim("px4", "udp:127.0.0.1:0", workdir=tmp) as sim:
        connect_to(sim.address)

The names below are loaded on first use (PEP 562): importing one submodule — the mock unit's
``magline.sim.storage``, the ``sim`` command's registration — loaded every simulator with pymavlink's
dialect and scipy's rotations, 0.24 s of every ``magline`` command's start (``magline spc`` included).
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from magline.sim.ardupilot import ArduPilotSim
    from magline.sim.faults import SimFaults
    from magline.sim.inav import InavSim
    from magline.sim.magnetometers import SimMagnetometer, device_id
    from magline.sim.px4 import Px4Sim
    from magline.sim.vehicle import Power, SimulatedAutopilot

_WHERE = {"ArduPilotSim": "ardupilot", "Px4Sim": "px4", "InavSim": "inav", "SimFaults": "faults",
          "SimMagnetometer": "magnetometers", "device_id": "magnetometers", "Power": "vehicle",
          "SimulatedAutopilot": "vehicle"}


def __getattr__(name: str) -> Any:
    if name == "FLAVOURS":
        return flavours()
    if name in _WHERE:
        return getattr(import_module(f"magline.sim.{_WHERE[name]}"), name)
    raise AttributeError(f"module 'magline.sim' has no attribute {name!r}")


def flavours() -> dict[str, type[SimulatedAutopilot]]:
    """The flight-controller simulators by the name ``magline sim`` and ``create_sim`` know them by."""
    from magline.sim.ardupilot import ArduPilotSim
    from magline.sim.inav import InavSim
    from magline.sim.px4 import Px4Sim

    return {"px4": Px4Sim, "ardupilot": ArduPilotSim, "inav": InavSim}


def create_sim(flavour: str, listen: str | None = None, **options: Any) -> SimulatedAutopilot:
    """A simulator of ``flavour`` (not started); ``listen`` defaults to the flavour's example address."""
    known = flavours()
    try:
        cls = known[flavour]
    except KeyError:
        raise ValueError(f"unknown simulator {flavour!r}; choose from {', '.join(known)}") from None
    return cls(listen, **options)


__all__ = ["FLAVOURS", "ArduPilotSim", "InavSim", "Power", "Px4Sim", "SimFaults", "SimMagnetometer",
           "SimulatedAutopilot", "create_sim", "device_id"]
