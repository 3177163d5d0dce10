"""A simulated flight controller's serial port: a pseudo-terminal behind links that stay in place.

What a board on USB does, reproduced so a station is tested against it (issue 48):

* **Names that stay, a node that does not.**  ``--listen serial:PATH`` makes ``PATH`` (and each
  ``--usb-alias``) a link to the pty's node, as udev's ``/dev/serial/by-path`` and ``by-id`` links
  point at ``/dev/ttyACM0``.  At a reboot or power loss the node goes away (the master closes, the
  links are removed); when the board is up again a new pty appears under the same links with
  another kernel number, as a board re-enumerating as ``ttyACM1`` does.
* **USB CDC ACM or a UART.**  Without a baud (``serial:PATH``) the port is a USB CDC ACM board: it
  ignores the line's baud (PX4's and ArduPilot's USB ports do) and carries what the firmware sends.
  With one (``serial:PATH:57600``) it is a UART behind a USB-serial adapter: it carries baud/10 bytes
  per second, drops a message its transmit buffer has no room for (as both firmwares do rather than
  block), and a station opening it at another baud reads framing garbage — and is not understood.
* **Nobody there.**  While no program has the port open, the board's output goes nowhere (the host
  does not read a closed CDC port); the first opening is a new peer the board greets at once.
* **The cable pulled.**  :meth:`unplug` removes the node for good (fault ``link_loss_after_s``).

The baud the station asked is read from the pty itself: on Linux the master sees the termios the
other side set.  Linux only (``os.openpty``, ``termios``), as the station is.
"""

from __future__ import annotations

import contextlib
import os
import select
import termios
import time
import tty
from pathlib import Path

TX_BUFFER_BYTES = 2048  # a firmware's serial transmit buffer: what does not fit is dropped, not queued
FIFO_BYTES = 64  # the UART's own FIFO: the most that leaves at once after a pause
BAUDS = {getattr(termios, f"B{b}"): b for b in (9600, 19200, 38400, 57600, 115200, 230400, 460800, 500000,
                                                  921600, 1000000, 1500000, 2000000) if hasattr(termios, f"B{b}")}


def garbled(data: bytes) -> bytes:
    """What a receiver at the wrong baud makes of ``data``: every byte misframed, some lost."""
    return bytes(((b * 0x9D) ^ 0x5A) & 0xFF for i, b in enumerate(data) if i % 3 != 2)


class PtyServerLink:
    """The ``ServerLink`` of a board on a serial port (see the module's docstring)."""

    bundling = "frame"

    def __init__(self, path: str, baud: int | None, aliases: tuple[str, ...] = ()) -> None:
        self.links = [Path(path), *(Path(a) for a in aliases)]
        self.baud = baud  # None: USB CDC ACM (the line's baud is ignored)
        self.address = f"serial:{path}:{baud}" if baud else f"serial:{path}"
        self.new_peer = False
        self.master: int | None = None
        self.device: str | None = None  # the pty's node now (/dev/pts/N), None while the board is away
        self.devices: list[str] = []  # every node the port had, in order (a test sees the number change)
        self._spare: tuple[int, str] | None = None
        self._connected = False
        self._unplugged = False
        self._out = bytearray()
        self._credit = 0.0
        self._paced_at = time.monotonic()
        self._busy = False  # bytes were waiting when the line was last paced: it has been sending since
        self.tx_dropped = 0  # messages the transmit buffer had no room for
        self.garbled_bytes = 0  # bytes exchanged at a baud other than the port's
        # … of them, once this node's line had been right: a station that opens the port and sets its baud a
        # moment later misframes what crosses in that moment, as on a real UART (at every node, so after each
        # reboot's re-enumeration too); after that, nothing may be
        self.garbled_after_framed = 0
        self._framed = False
        for link in self.links:
            link.parent.mkdir(parents=True, exist_ok=True)
        self._plug()

    # ------------------------------------------------------------------ the node
    def _new_pty(self) -> tuple[int, str]:
        master, slave = os.openpty()
        tty.setraw(slave)  # a board's port carries bytes, not lines (the station sets raw too)
        name = os.ttyname(slave)
        os.close(slave)  # only the station holds the port's node: ``fuser`` names nobody else
        os.set_blocking(master, False)
        return master, name

    def _plug(self) -> None:
        self.master, self.device = self._spare or self._new_pty()
        self._spare = None
        self.devices.append(self.device)
        self._connected, self._out = False, bytearray()
        self._framed = False  # a new node starts at the kernel's default speed: its opening has its moment too
        for link in [*self.links[1:], self.links[0]]:  # the station's name last, its other names ready then
            staged = link.with_name(link.name + ".new")
            with contextlib.suppress(FileNotFoundError):
                staged.unlink()
            os.symlink(self.device, staged)
            os.replace(staged, link)  # the name never points nowhere while it moves

    def _unplug_node(self) -> None:
        for link in self.links:
            with contextlib.suppress(FileNotFoundError):
                link.unlink()
        if self.master is not None:
            os.close(self.master)
        self.master, self.device, self._connected = None, None, False
        self._out = bytearray()

    # ------------------------------------------------------------------ ServerLink
    def poll(self, timeout: float, up: bool) -> list[tuple[object, bytes]]:
        if self.master is None:
            if up and not self._unplugged:
                self._plug()
            else:
                time.sleep(timeout)
                return []
        poller = select.poll()
        poller.register(self.master, select.POLLIN)
        events = poller.poll(timeout * 1000.0)
        if any(ev & select.POLLHUP for _, ev in events):  # nobody has the port open
            self._connected, self._out = False, bytearray()
            time.sleep(timeout)
            return []
        if not self._connected:
            self._connected = self.new_peer = True
            self._paced_at, self._credit, self._busy = time.monotonic(), 0.0, False
        self._flush()
        try:
            data = os.read(self.master, 65536)
        except (BlockingIOError, InterruptedError):
            return []
        except OSError:  # EIO: the station closed the port between the poll and the read
            self._connected = False
            return []
        if self._misframed():
            self._count_garbled(len(data))
            data = garbled(data)
        return [("serial", data)] if up and data else []

    def send(self, data: bytes) -> None:
        if self.master is None or not self._connected:
            return
        if self.baud is not None and len(self._out) + len(data) > TX_BUFFER_BYTES:
            self.tx_dropped += 1
            return
        if self._misframed():
            self._count_garbled(len(data))
            data = garbled(data)
        self._out += data
        self._flush()

    def _count_garbled(self, size: int) -> None:
        self.garbled_bytes += size
        if self._framed:
            self.garbled_after_framed += size

    def _misframed(self) -> bool:
        """The station opened a UART at another baud than the board's."""
        if self.baud is None or self.master is None:
            return False
        try:
            speed = termios.tcgetattr(self.master)[4]
        except termios.error:
            return False
        wrong = BAUDS.get(speed) != self.baud
        self._framed = self._framed or (not wrong and self._connected)
        return wrong

    def _flush(self) -> None:
        if not self._out or self.master is None:
            return
        size = len(self._out)
        if self.baud is not None:  # a UART: baud/10 bytes per second (8N1), a FIFO's worth after a pause
            now = time.monotonic()
            rate = self.baud / 10.0
            earned = self._credit + (now - self._paced_at) * rate
            # a line with bytes waiting sent them at its rate however late this thread came back (a UART does
            # not pause for the firmware's scheduler); an idle one lets a FIFO's worth go at once.  Capped at
            # one flush's worth, a loaded machine's late thread made the line carry half its baud
            self._credit = min(earned, size) if self._busy else min(earned, max(FIFO_BYTES, rate * 0.01))
            self._paced_at = now
            size = min(size, int(self._credit))
        if size <= 0:
            return
        try:
            written = os.write(self.master, bytes(self._out[:size]))
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            self._connected, self._out = False, bytearray()
            return
        del self._out[:written]
        if self.baud is not None:
            self._credit -= written
            self._busy = bool(self._out)

    def drop_peers(self) -> None:
        """A reboot or power loss: the node vanishes now; the next one is taken already, so it gets
        another kernel number (the old one stays while the station still holds it)."""
        if self.master is None:
            return
        self._spare = self._spare or self._new_pty()
        self._unplug_node()

    def unplug(self) -> None:
        self._unplugged = True
        self._unplug_node()

    def close(self) -> None:
        self._unplug_node()
        if self._spare is not None:
            os.close(self._spare[0])
            self._spare = None
