"""The simulator's end of the link: a UDP or TCP server socket on a real address, or a serial port
(a pseudo-terminal behind a link that stays in place, as udev's ``/dev/serial/by-path`` names do).

Why servers: a backend must reach the simulator exactly as it reaches a board on a network
(``udpout://127.0.0.1:14550`` for MAVSDK, ``tcp:127.0.0.1:5760`` for pymavlink), so the
simulator listens and learns its peers from what they send.  Both links can be taken down the
way a rebooting board does it: TCP closes its connections and accepts no new ones until the
board is up again; UDP forgets its peers and drops what arrives meanwhile.  A serial port does
what a USB CDC ACM board does: its node vanishes at the reboot and a new one (another kernel number)
appears under the same names when the board is up again (:mod:`magline.sim.pty_port`).
"""

from __future__ import annotations

import contextlib
import select
import socket
from typing import Protocol


class AddressError(ValueError):
    """A ``--listen`` address that is not ``udp:HOST:PORT``, ``tcp:HOST:PORT`` or ``serial:PATH[:BAUD]``."""


def parse_peer(address: str, what: str) -> tuple[str, int]:
    """(host, port) of a simulator another one reaches (``--gimbal tcp:HOST:PORT``); ``what`` names it in the
    error.  Why: a wrong one was said as Python's "not enough values to unpack"."""
    try:
        scheme, host, port = parse_listen(address)
    except AddressError:
        scheme, host, port = "", "", 0
    if scheme != "tcp" or not host or port == 0:
        raise AddressError(f"{what} {address!r}: expected tcp:HOST:PORT with a port from 1 to 65535")
    return host, port


def parse_listen(address: str) -> tuple[str, str, int]:
    """(scheme, host or path, port or baud; 0 for a serial port without one)."""
    if address.startswith("serial:"):
        path, _, baud = address.removeprefix("serial:").rpartition(":")
        if not path or not baud.isdigit():  # no baud (udev names have colons): USB CDC ACM, which ignores it
            path, baud = address.removeprefix("serial:"), "0"
        if not path.startswith("/"):
            raise AddressError(f"listen address {address!r}: expected serial:PATH[:BAUD] with an absolute PATH "
                               "(the link the simulator keeps pointing at its pseudo-terminal)")
        return "serial", path, int(baud)
    try:
        scheme, host, port = address.split(":")
        if scheme not in ("udp", "tcp"):
            raise ValueError(scheme)
        number = int(port)
    except ValueError as exc:
        raise AddressError(f"listen address {address!r}: expected udp:HOST:PORT, tcp:HOST:PORT or "
                           "serial:PATH[:BAUD]") from exc
    if not 0 <= number <= 65535:  # the socket refuses it with an OverflowError, no OSError
        raise AddressError(f"listen address {address!r}: {number} is not a port (0 to 65535; 0: any free one)")
    return scheme, host, number


class ServerLink(Protocol):
    address: str
    new_peer: bool
    # how a bundle of frames sent at once is written: "stream" (TCP) in one write, "datagram" (UDP) in
    # packets of whole frames, "frame" (a serial port's transmit buffer, which drops frames whole) one by one
    bundling: str

    def poll(self, timeout: float, up: bool) -> list[tuple[object, bytes]]:
        """Bytes received per peer within ``timeout``; while not ``up`` nothing is accepted."""

    def send(self, data: bytes) -> None:
        """Send to every known peer."""

    def drop_peers(self) -> None:
        """Forget (UDP) or close (TCP) every peer, or take the serial node away: what a reboot or power
        loss does."""

    def unplug(self) -> None:
        """The link is lost for good (fault ``link_loss_after_s``): a network link goes silent, a USB
        board's node vanishes as when its cable is pulled."""

    def close(self) -> None: ...


class UdpServerLink:
    bundling = "datagram"

    def __init__(self, host: str, port: int) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((host, port))
        self.address = f"udp:{host}:{self.sock.getsockname()[1]}"
        self.peers: set[tuple[str, int]] = set()
        self.new_peer = False  # set when a peer appears; the board greets it with a heartbeat

    def poll(self, timeout: float, up: bool) -> list[tuple[object, bytes]]:
        out: list[tuple[object, bytes]] = []
        ready, _, _ = select.select([self.sock], [], [], timeout)
        while ready:
            try:
                data, peer = self.sock.recvfrom(65535)
            except OSError:
                break
            if up:
                self.new_peer |= peer not in self.peers
                self.peers.add(peer)
                out.append((peer, data))
            ready, _, _ = select.select([self.sock], [], [], 0)
        return out

    def send(self, data: bytes) -> None:
        for peer in list(self.peers):
            with contextlib.suppress(OSError):
                self.sock.sendto(data, peer)

    def drop_peers(self) -> None:
        self.peers.clear()

    def unplug(self) -> None:
        return None

    def close(self) -> None:
        self.sock.close()


class TcpServerLink:
    bundling = "stream"

    def __init__(self, host: str, port: int) -> None:
        self.listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.listener.bind((host, port))
        self.listener.listen(4)
        self.address = f"tcp:{host}:{self.listener.getsockname()[1]}"
        self.clients: list[socket.socket] = []
        self.new_peer = False

    def poll(self, timeout: float, up: bool) -> list[tuple[object, bytes]]:
        watch = [*self.clients, self.listener] if up else list(self.clients)
        if not watch:
            select.select([], [], [], timeout)
            return []
        ready, _, _ = select.select(watch, [], [], timeout)
        out: list[tuple[object, bytes]] = []
        for sock in ready:
            if sock is self.listener:
                client, _ = self.listener.accept()
                client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                self.clients.append(client)
                self.new_peer = True
                continue
            try:
                data = sock.recv(65535)
            except OSError:
                data = b""
            if not data:
                self._drop(sock)
            elif up:
                out.append((sock, data))
        return out

    def send(self, data: bytes) -> None:
        for client in list(self.clients):
            try:
                client.sendall(data)
            except OSError:
                self._drop(client)

    def _drop(self, client: socket.socket) -> None:
        if client in self.clients:
            self.clients.remove(client)
        with contextlib.suppress(OSError):
            client.close()

    def drop_peers(self) -> None:
        for client in list(self.clients):
            self._drop(client)

    def unplug(self) -> None:
        return None

    def close(self) -> None:
        self.drop_peers()
        self.listener.close()


def open_server(address: str, aliases: tuple[str, ...] = ()) -> ServerLink:
    """The board's end of ``address``; ``aliases``: more names of a serial port (its udev by-id link)."""
    scheme, host, port = parse_listen(address)
    if scheme == "serial":
        from magline.sim.pty_port import PtyServerLink

        return PtyServerLink(host, port or None, aliases)
    return UdpServerLink(host, port) if scheme == "udp" else TcpServerLink(host, port)
