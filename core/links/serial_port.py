"""A flight controller on a serial port, as a line plugs it in: named by the fixture's physical port
(``/dev/serial/by-path/…``) or by the board's own USB serial (``/dev/serial/by-id/…``), gone while
the board reboots and back — perhaps under another kernel number — after it.

Why a module of its own: both MAVLink backends (MAVSDK and pymavlink) open a device *path*; what
a station needs around that is the same for both and for any later firmware: wait for the node
under the name the station file gives, say plainly why it cannot be opened (absent, permission,
held by another program), and prove the board that comes back is the one that left (the same port
and the same USB serial).  udev's layout is the contract: ``/dev/serial/by-id`` and
``/dev/serial/by-path`` hold links to the kernel's node; a name under another folder that has
``by-id`` and ``by-path`` sub-folders is read the same way (the simulators lay one out in a temp
folder).  See ``docs/connecting-units.md``.
"""

from __future__ import annotations

import grp
import os
import re
import shutil
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

from magline.core.dut import LinkError
from magline.core.faults import StationFault, StreamTooFast

DEFAULT_BAUD = 115200
UDEV_ROOT = Path("/dev/serial")
NAMINGS = ("by-path", "by-id")
SERIAL_HINT = ("over a serial port, silence means a wrong baud or a device that is not a flight controller "
               "(`magline ports` lists what is plugged in)")


class SerialAddressError(ValueError):
    """A ``serial:`` connection string that names no device or no numeric baud."""


@dataclass(frozen=True)
class SerialAddress:
    """``serial:DEVICE[:BAUD]`` or ``serial://DEVICE[:BAUD]`` (a bare ``/dev/…`` path too)."""

    path: str
    baud: int

    @classmethod
    def parse(cls, connection: str) -> SerialAddress | None:
        """The serial port a station's connection names, None for a network link."""
        if connection.startswith("serial://"):
            rest = connection.removeprefix("serial://")
        elif connection.startswith("serial:"):
            rest = connection.removeprefix("serial:")
        elif connection.startswith("/dev/"):
            rest = connection
        else:
            return None
        device, _, baud = rest.rpartition(":")
        if not device or not baud.isdigit():  # no baud: the tail is the path's own (by-path names end ":1.0")
            device, baud = rest, str(DEFAULT_BAUD)
        if not device.startswith("/") or int(baud) <= 0:
            raise SerialAddressError(f"connection {connection!r}: expected serial:DEVICE:BAUD with an absolute "
                                     "DEVICE path, e.g. serial:/dev/serial/by-path/…:115200")
        return cls(device, int(baud))

    @property
    def mavsdk_url(self) -> str:
        return f"serial://{self.path}:{self.baud}"

    def __str__(self) -> str:
        return f"serial:{self.path}:{self.baud}"


@dataclass(frozen=True)
class UsbIdentity:
    """Who a serial port is: the kernel's node and the udev names pointing at it."""

    device: str  # /dev/ttyACM0 (a simulator's: /dev/pts/N)
    by_path: str | None = None  # the fixture's hub port: /dev/serial/by-path/…-usb-0:3:1.0
    by_id: str | None = None  # the board's USB serial: /dev/serial/by-id/usb-…_<serial>-if00

    def words(self) -> str:
        names = [n for n in (self.by_path, self.by_id) if n]
        return f"{self.device} ({', '.join(names)})" if names else self.device


@dataclass(frozen=True)
class PortListing:
    """One serial port as ``magline ports`` shows it."""

    device: str
    by_path: str | None
    by_id: str | None
    description: str = ""  # vendor and model where udev says them


def udev_root(named: str | Path) -> Path:
    """The ``/dev/serial`` folder a name belongs to (its parent's parent for a by-id/by-path name)."""
    path = Path(named)
    return path.parent.parent if path.parent.name in NAMINGS else UDEV_ROOT


def identity_of(named: str | Path) -> UsbIdentity:
    """The node ``named`` resolves to now, with every udev name pointing at it."""
    device = os.path.realpath(named)
    root = udev_root(named)
    found: dict[str, str | None] = {"by-path": None, "by-id": None}
    for naming in NAMINGS:
        folder = root / naming
        if not folder.is_dir():
            continue
        for link in sorted(folder.iterdir()):
            if os.path.realpath(link) == device:
                found[naming] = str(link)
                break
    return UsbIdentity(device=device, by_path=found["by-path"], by_id=found["by-id"])


def list_ports(root: Path | None = None) -> list[PortListing]:
    """What is plugged in: every node under ``root``'s by-path and by-id names (udev's layout), each
    once, with vendor and model from udev where the machine has it (pyudev)."""
    root = root or UDEV_ROOT
    names: dict[str, dict[str, str]] = {}
    for naming in NAMINGS:
        folder = root / naming
        if not folder.is_dir():
            continue
        for link in sorted(folder.iterdir()):
            if os.path.exists(link):
                names.setdefault(os.path.realpath(link), {})[naming] = str(link)
    if root == UDEV_ROOT:  # nodes udev gave no names (a machine without udev rules for them)
        for node in sorted(Path("/dev").glob("tty[AU][CS][MB]*")):
            names.setdefault(str(node), {})
    described = _udev_descriptions(list(names)) if root == UDEV_ROOT else {}
    return [PortListing(device=d, by_path=n.get("by-path"), by_id=n.get("by-id"), description=described.get(d, ""))
            for d, n in sorted(names.items())]


def _udev_descriptions(devices: list[str]) -> dict[str, str]:
    """Vendor and model of each node as udev knows them ({} where there is no udev)."""
    try:
        import pyudev
    except ImportError:
        return {}
    try:
        context = pyudev.Context()
        out = {}
        for device in devices:
            props = pyudev.Devices.from_device_file(context, device).properties
            words = [props.get("ID_VENDOR_FROM_DATABASE") or props.get("ID_VENDOR"), props.get("ID_MODEL"),
                     props.get("ID_SERIAL_SHORT") and f"serial {props.get('ID_SERIAL_SHORT')}"]
            out[device] = " ".join(w.replace("_", " ") for w in words if w)
        return out
    except Exception:  # no udev database (a container): the names alone
        return {}


def plugged_in_words(named: str | Path) -> str:
    """What ``magline ports`` would list, in one clause for an error message."""
    ports = list_ports(udev_root(named))
    if not ports:
        return f"nothing is plugged in under {udev_root(named)}"
    return "plugged in: " + "; ".join(p.by_path or p.by_id or p.device for p in ports)


def wait_present(address: SerialAddress, timeout_s: float, what: str = "the unit") -> None:
    """Return once the node ``address`` names exists (a board re-enumerating after its reboot comes
    back within the boot timeout); a LinkError naming it and what is plugged in otherwise."""
    deadline = time.monotonic() + timeout_s
    while not os.path.exists(address.path):
        if time.monotonic() >= deadline:
            raise LinkError(f"{address.path} is not there: {what} did not appear within {timeout_s:g} s "
                            f"({plugged_in_words(address.path)})")
        time.sleep(0.05)


def check_usable(address: SerialAddress) -> None:
    """Before opening: the station may read and write the node and no other program holds it (a
    ground station, ModemManager probing a new "modem") — each said with what to do, never a hang."""
    device = os.path.realpath(address.path)
    if not os.access(device, os.R_OK | os.W_OK):
        group = _group_of(device)
        raise StationFault(f"permission denied on {device} (named {address.path}): the station's user must be in "
                           f"the group {group!r} (sudo usermod -aG {group} $USER, then log in again)")
    held = holders(device)
    if held:
        raise StationFault(f"{address.path} is held by {', '.join(held)}: close it, or tell ModemManager to leave "
                           "flight controllers alone (docs/connecting-units.md)")


def _group_of(device: str) -> str:
    try:
        return grp.getgrgid(os.stat(device).st_gid).gr_name
    except (KeyError, OSError):
        return "dialout"


def holders(device: str) -> list[str]:
    """Other processes with ``device`` open, as "name (pid N)": ``fuser`` (psmisc) where installed,
    else the same reading of /proc.  Processes the system hides from this user are not seen."""
    pids: set[int] = set()
    fuser = shutil.which("fuser")
    if fuser:
        done = subprocess.run([fuser, device], capture_output=True, text=True, timeout=10, check=False)
        pids = {int(p) for p in re.findall(r"\d+", done.stdout)}
    else:
        for fd_dir in Path("/proc").glob("[0-9]*/fd"):
            try:
                if any(os.path.realpath(fd) == device for fd in fd_dir.iterdir()):
                    pids.add(int(fd_dir.parent.name))
            except OSError:
                continue
    pids.discard(os.getpid())
    return [f"{_command_of(pid)} (pid {pid})" for pid in sorted(pids)]


def _command_of(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/comm").read_text(encoding="utf-8").strip()
    except OSError:
        return "a process"


def same_board(before: UsbIdentity, now: UsbIdentity, named: str, back: bool = True) -> None:
    """The board under ``named`` (``back``: come back after its reboot; else: now, mid-run) is on the
    same port with the same USB serial, else a LinkError naming both (a board moved, another board in
    the port, a hub re-enumerating)."""
    if before.by_id and now.by_id and before.by_id != now.by_id:
        change = "came back as" if back else "is now"
        raise LinkError(f"the board on {named} {change} {now.by_id}, not {before.by_id}: another board; "
                        "nothing is written to it")
    if before.by_path and now.by_path and before.by_path != now.by_path:
        change = "came back" if back else "is now"
        raise LinkError(f"the board {named} {change} on another port, {now.by_path}, not {before.by_path}: "
                        "nothing is written to it")


MAVLINK2_OVERHEAD = 12  # a MAVLink 2 frame: 10 header bytes and a 2-byte checksum around the payload
LINE_SHARE = 0.9  # of what a UART carries, the most a stream may take: the board sends heartbeats and more


def mavlink2_frame_bytes(msg_id: int) -> int:
    """A MAVLink message's frame at its longest (the whole payload, extensions included, and the MAVLink 2
    header and checksum): what one message takes of a serial line."""
    from pymavlink.dialects.v20 import common  # imported on use: only a serial link's capacity check asks

    return int(common.mavlink_map[msg_id].unpacker.size) + MAVLINK2_OVERHEAD


def ignores_baud(node: str) -> bool:
    """A USB CDC ACM port (the kernel's ``cdc_acm`` driver: ttyACM) carries what USB carries whatever baud
    is set; a UART behind a USB-serial adapter (ttyUSB) or on the board (ttyS, ttyAMA) carries baud/10
    bytes a second.  A node the kernel does not say (a simulator's pty) is taken at its baud."""
    driver = Path("/sys/class/tty") / Path(node).name / "device" / "driver"
    return driver.exists() and driver.resolve().name == "cdc_acm"


class SerialPortWatch:
    """One unit's serial port for the run: ready to open (present, permitted, not held) and the
    same board each time it is opened again."""

    def __init__(self, address: SerialAddress) -> None:
        self.address = address
        self.first: UsbIdentity | None = None

    def ready(self, timeout_s: float, what: str = "the unit") -> UsbIdentity:
        deadline = time.monotonic() + timeout_s
        wait_present(self.address, timeout_s, what)
        check_usable(self.address)
        now = identity_of(self.address.path)
        if self.first is None:
            self.first = now
            return now
        # udev makes a node's names one after the other: the one the station named may be back before
        # the other, which says whether this is the same board — wait for it, as for the node
        while self._names_missing(now) and time.monotonic() < deadline:
            time.sleep(0.05)
            now = identity_of(self.address.path)
        missing = self._names_missing(now)
        if missing:
            raise LinkError(f"the board on {self.address.path} came back without its {' and '.join(missing)} name "
                            f"within {timeout_s:g} s: not proven the same board; nothing is written to it")
        same_board(self.first, now, self.address.path)
        return now

    def _names_missing(self, now: UsbIdentity) -> list[str]:
        first = self.first
        assert first is not None
        pairs = (("by-path", first.by_path, now.by_path), ("by-id", first.by_id, now.by_id))
        return [naming for naming, was, is_ in pairs if was and not is_]

    def require_capacity(self, streams: dict[str, tuple[int, float]],
                         beside: dict[str, tuple[int, float]] | None = None) -> None:
        """Before a stream is asked (name → (frame bytes, messages a second)), with what is sent ``beside``
        it at a rate of its own (the battery's current during a sweep): a UART at the station's baud
        carries them, else a :class:`StreamTooFast` with the figures and the rate the stream fits at beside
        the rest — said before the tumble, not found as a short one (the firmware drops what its transmit
        buffer cannot hold)."""
        node = os.path.realpath(self.address.path)
        if ignores_baud(node):
            return
        beside = beside or {}
        fixed = sum(size * rate for size, rate in beside.values())
        need = sum(size * rate for size, rate in streams.values()) + fixed
        line = self.address.baud / 10.0  # 8N1: ten bits a byte
        if need > LINE_SHARE * line:
            asked = ", ".join(f"{name} {rate:g}/s" for name, (_, rate) in {**streams, **beside}.items())
            per_hz = sum(size * rate for size, rate in streams.values()) / max(rate for _, rate in streams.values())
            fits_hz = max(LINE_SHARE * line - fixed, 0.0) / per_hz
            raise StreamTooFast(f"{self.address.path} at {self.address.baud} baud carries {line:,.0f} bytes/s; the "
                                f"stream asked ({asked}) needs {need:,.0f} bytes/s: raise the baud (on the board and "
                                "in the station file), connect the board's USB port, or lower the stream's rate: "
                                "acquisition.rate_hz for the tumble, interference.rate_hz for the current sweep",
                                fits_hz)

    def still_at(self, node: str | None) -> bool:
        """The station's name still points at ``node`` (it did not vanish or move meanwhile)."""
        return node is not None and os.path.exists(node) and os.path.realpath(self.address.path) == node

    def require_same(self) -> None:
        """Before a write: the node the station named is still the board it opened."""
        if self.first is None:
            return
        if not os.path.exists(self.address.path):
            raise LinkError(f"{self.address.path} is gone (the cable pulled, or the board reset): nothing is written")
        same_board(self.first, identity_of(self.address.path), self.address.path, back=False)
