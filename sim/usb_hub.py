"""A simulated USB hub with per-port power switching, as ``uhubctl`` drives real ones (issue 48).

Switching a port off powers down a board that takes its power from USB (``usb_powered``) and takes its
serial node away; switching it on boots it.  A board with a supply of its own keeps running: only its
node goes and comes back, as a hub re-enumerating it does.  The hub is reached by the stand-in
``uhubctl`` (:mod:`magline.sim.uhubctl`) over a small SCPI-style protocol on TCP: ``LOC?`` (its
location, ``1-1``), ``PORTS?`` (how many), ``PORT? N`` (``1`` powered, ``0`` off), ``PORT N,ON|OFF``,
``DEV? N`` (what is plugged into port N).
"""

from __future__ import annotations

from magline.sim.scpi_server import ScpiServer
from magline.sim.vehicle import SimulatedAutopilot


class UsbHubSim(ScpiServer):
    identity = "magline,SIM-USB-HUB,0001,1.0"

    def __init__(self, listen: str = "tcp:127.0.0.1:5040", location: str = "1-1", ports: int = 4,
                 boards: dict[int, SimulatedAutopilot] | None = None, per_port: bool = True) -> None:
        super().__init__(listen)
        self.per_port = per_port  # False: a hub without per-port power switching ("ganged"): OFF is ignored
        self.location = location
        self.ports = ports
        self.boards = dict(boards or {})
        self.powered = {n: True for n in range(1, ports + 1)}

    def command(self, head: str, arg: str) -> str | None:
        if head == "LOC?":
            return self.location
        if head == "PORTS?":
            return str(self.ports)
        if head in ("PORT?", "DEV?", "PORT"):
            number, _, state = arg.partition(",")
            port = int(number)
            if port not in self.powered:
                self.errors.append('-222,"Data out of range"')
                return "" if head.endswith("?") else None
            if head == "PORT?":
                return "1" if self.powered[port] else "0"
            if head == "DEV?":
                board = self.boards.get(port)
                return f"26ac:0032 PX4 FMU {board.flavour}" if board is not None and self.powered[port] else ""
            if state.strip().upper() not in ("ON", "OFF"):
                self.errors.append('-224,"Illegal parameter value"')
                return None
            if not self.per_port:
                return None
            self.powered[port] = state.strip().upper() == "ON"
            board = self.boards.get(port)
            if board is not None:
                board.usb_power(self.powered[port])
            return None
        raise KeyError(head)
