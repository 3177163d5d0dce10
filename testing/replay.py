"""Replay a recorded unit (``magline run --record-mavlink FILE``) to a backend: a bug seen on the
line becomes a test.

The replay plays the vehicle: it sends the vehicle's recorded packets in their recorded order and
spacing, and where the recording shows the station speaking (a PARAM_SET, a COMMAND_LONG, a
request) it waits until the backend under test sends a message of that type before going on, so
the vehicle's answers come after the questions as they did on the line.  The station's own
heartbeats are not waited for.  A link the backend closes and opens again (a reboot) continues
where the recording is.

    with mavlink_replay("unit.tlog") as vehicle:
        station = station_file(tmp_path, {"products": {"AP-QUAD-200": {"connection": vehicle.connection}}},
                               base="ardupilot-sim.yaml")
"""

from __future__ import annotations

import collections
import socket
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

INVALID_AUTOPILOT = 8  # MAV_AUTOPILOT_INVALID: a ground station's heartbeat


@dataclass
class Packet:
    t: float
    from_vehicle: bool
    kind: str
    raw: bytes


def read_tlog(path: str | Path) -> list[Packet]:
    """The recorded packets, each marked as the vehicle's or the station's (by system id: the
    vehicle's is the one whose heartbeat names an autopilot)."""
    from pymavlink import mavutil

    log = mavutil.mavlink_connection(str(path))
    messages = []
    while (message := log.recv_match()) is not None:
        messages.append(message)
    vehicle = next((m.get_srcSystem() for m in messages
                    if m.get_type() == "HEARTBEAT" and m.autopilot != INVALID_AUTOPILOT), None)
    if vehicle is None:
        raise ValueError(f"{path}: no vehicle heartbeat in the recording")
    return [Packet(m._timestamp, m.get_srcSystem() == vehicle, m.get_type(), bytes(m.get_msgbuf()))
            for m in messages if m.get_type() != "BAD_DATA"]


class ReplayVehicle:
    """A TCP server that plays the recorded vehicle to whoever connects (``connection``)."""

    def __init__(self, packets: list[Packet], speed: float = 1.0, max_gap_s: float = 0.5,
                 answer_timeout_s: float = 5.0) -> None:
        self.packets = packets
        self.speed, self.max_gap_s, self.answer_timeout_s = speed, max_gap_s, answer_timeout_s
        self.index = 0  # where the recording is (shared by successive links)
        self.skipped: list[str] = []  # station messages of the recording the backend never sent
        self.server = socket.create_server(("127.0.0.1", 0))
        self.server.settimeout(0.2)
        self.connection = f"tcp:127.0.0.1:{self.server.getsockname()[1]}"
        self._stop = threading.Event()
        threading.Thread(target=self._accept, name="magline-replay", daemon=True).start()

    @property
    def finished(self) -> bool:
        return self.index >= len(self.packets)

    def close(self) -> None:
        self._stop.set()
        self.server.close()

    def _accept(self) -> None:
        from magline.core.links.mavlink_tap import accepted_links

        for client in accepted_links(self.server, self._stop):
            self._serve(client)

    def _serve(self, client: socket.socket) -> None:
        from magline.core.links.mavlink_tap import packet_parser, received

        heard: collections.Counter[str] = collections.Counter()
        gone = threading.Event()
        lock = threading.Condition()

        def listen() -> None:
            parser = packet_parser()
            for data in received(client, self._stop):
                with lock:
                    for message in parser.parse_buffer(data) or []:
                        heard[message.get_type()] += 1
                    lock.notify_all()
            gone.set()
            with lock:
                lock.notify_all()

        threading.Thread(target=listen, daemon=True).start()
        with client:
            last_t: float | None = None
            while not self._stop.is_set() and not gone.is_set() and not self.finished:
                packet = self.packets[self.index]
                if packet.from_vehicle:
                    if last_t is not None:
                        time.sleep(min(max(packet.t - last_t, 0.0), self.max_gap_s) / self.speed)
                    last_t = packet.t
                    try:
                        client.sendall(packet.raw)
                    except OSError:
                        break
                elif packet.kind != "HEARTBEAT":
                    with lock:
                        if not lock.wait_for(lambda k=packet.kind: heard[k] > 0 or gone.is_set(),
                                             self.answer_timeout_s):
                            self.skipped.append(packet.kind)
                        elif heard[packet.kind] > 0:
                            heard[packet.kind] -= 1
                    if gone.is_set():
                        break  # the backend closed the link (a reboot): the next link goes on from here
                self.index += 1


@contextmanager
def mavlink_replay(tlog: str | Path, **options: Any) -> Iterator[ReplayVehicle]:
    """Serve ``tlog``'s vehicle on a free loopback TCP port (``.connection``) while the block runs."""
    vehicle = ReplayVehicle(read_tlog(tlog), **options)
    try:
        yield vehicle
    finally:
        vehicle.close()
