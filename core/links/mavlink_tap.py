"""``magline run --record-mavlink FILE``: every MAVLink packet between a backend and its vehicle,
both ways, kept in a telemetry log (tlog) that pymavlink, MAVProxy and QGroundControl read.

Why a loopback proxy rather than a hook in each backend: the PX4 backend talks through MAVSDK,
whose traffic never passes through magline's code; a proxy between the backend and the vehicle
sees exactly what went over the wire for any backend.  The station's connection string is
pointed at the proxy; the proxy forwards to the real address.

tlog format: for each packet, its arrival time as a big-endian uint64 of microseconds since the
epoch, then the packet's bytes.
"""

from __future__ import annotations

import contextlib
import socket
import struct
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any, BinaryIO

BUFFER = 65536


def packet_parser() -> Any:
    """A pymavlink parser that skips what it cannot read (a link's bytes, any dialect message)."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    return parser


def _split(connection: str) -> tuple[str, str, int]:
    """``tcp:H:P`` / ``tcpout://H:P`` / ``udpout://H:P`` / ``udpout:H:P`` → (tcp|udp, host, port)."""
    scheme, _, rest = connection.partition(":")
    rest = rest.removeprefix("//")
    host, _, port = rest.rpartition(":")
    kinds = {"tcp": "tcp", "tcpout": "tcp", "udpout": "udp"}
    if scheme not in kinds or not port.isdigit():
        raise ValueError(f"--record-mavlink cannot tap {connection!r} (it taps tcp:, tcpout:// and udpout:// links)")
    return kinds[scheme], host, int(port)


def can_tap(connection: str) -> bool:
    try:
        _split(connection)
    except ValueError:
        return False
    return True


def received(link: socket.socket, stop: threading.Event) -> Iterator[bytes]:
    """What arrives on ``link`` (polled every 0.2 s) until it closes, fails or ``stop`` is set."""
    link.settimeout(0.2)
    while not stop.is_set():
        try:
            data = link.recv(BUFFER)
        except TimeoutError:
            continue
        except OSError:
            return
        if not data:
            return
        yield data


def accepted_links(server: socket.socket, stop: threading.Event) -> Iterator[socket.socket]:
    """Each link accepted on ``server`` (with a short accept timeout) until ``stop`` is set."""
    while not stop.is_set():
        try:
            client, _ = server.accept()
        except (TimeoutError, OSError):
            continue
        yield client


class _Log:
    """The tlog file, written packet by packet from several pump threads."""

    def __init__(self, path: Path) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        self.file: BinaryIO = path.open("wb")
        self.lock = threading.Lock()
        self.packets = 0

    def feed(self, parser: Any, data: bytes) -> None:
        for message in parser.parse_buffer(data) or []:
            stamp = struct.pack(">Q", int(time.time() * 1e6))
            with self.lock:
                self.file.write(stamp + message.get_msgbuf())
                self.packets += 1

    def close(self) -> None:
        with self.lock:
            self.file.close()


class MavlinkTap:
    """A proxy for one vehicle link; ``connection`` is what the station connects to instead."""

    def __init__(self, connection: str, tlog: Path) -> None:
        self.kind, self.host, self.port = _split(connection)
        self.log = _Log(Path(tlog))
        self.tlog = Path(tlog)
        self._stop = threading.Event()
        self._sockets: list[socket.socket] = []
        if self.kind == "tcp":
            self.listener = socket.create_server(("127.0.0.1", 0))
            self.listener.settimeout(0.2)
            self._thread(self._accept)
        else:
            self.listener = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self.listener.bind(("127.0.0.1", 0))
            self.listener.settimeout(0.2)
            self.upstream = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self.upstream.settimeout(0.2)
            self._station: tuple[str, int] | None = None
            self._thread(self._udp_out)
            self._thread(self._udp_in)
        port = self.listener.getsockname()[1]
        self.connection = (f"tcp:127.0.0.1:{port}" if connection.startswith("tcp:") else
                           f"{connection.split(':', 1)[0]}://127.0.0.1:{port}")

    def _thread(self, target: Any, *args: Any) -> None:
        threading.Thread(target=target, args=args, name="magline-mavlink-tap", daemon=True).start()

    # ------------------------------------------------------------------ TCP: one upstream link per accepted link
    def _accept(self) -> None:
        for client in accepted_links(self.listener, self._stop):
            try:
                upstream = socket.create_connection((self.host, self.port), timeout=5.0)
            except OSError:
                client.close()  # the vehicle is not there (booting): the backend retries, as it would
                continue
            self._sockets += [client, upstream]
            self._thread(self._pump, client, upstream, packet_parser())
            self._thread(self._pump, upstream, client, packet_parser())

    def _pump(self, source: socket.socket, target: socket.socket, parser: Any) -> None:
        for data in received(source, self._stop):
            self.log.feed(parser, data)
            try:
                target.sendall(data)
            except OSError:
                break
        for s in (source, target):  # one side closed: so is the other, as on a direct link
            with contextlib.suppress(OSError):
                s.shutdown(socket.SHUT_RDWR)

    # ------------------------------------------------------------------ UDP: the station's datagrams and the vehicle's
    def _udp_out(self) -> None:
        parser = packet_parser()
        while not self._stop.is_set():
            try:
                data, self._station = self.listener.recvfrom(BUFFER)
            except (TimeoutError, OSError):
                continue
            self.log.feed(parser, data)
            try:
                self.upstream.sendto(data, (self.host, self.port))
            except OSError:
                continue

    def _udp_in(self) -> None:
        parser = packet_parser()
        while not self._stop.is_set():
            try:
                data = self.upstream.recv(BUFFER)
            except (TimeoutError, OSError):
                continue
            self.log.feed(parser, data)
            if self._station is not None:
                try:
                    self.listener.sendto(data, self._station)
                except OSError:
                    continue

    def close(self) -> None:
        self._stop.set()
        time.sleep(0.3)  # the pumps see the flag within their 0.2 s timeouts
        for s in [self.listener, *self._sockets, *([self.upstream] if self.kind == "udp" else [])]:
            s.close()
        self.log.close()
