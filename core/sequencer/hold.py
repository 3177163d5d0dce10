"""One run per shared thing, held with operating-system file locks: locks guard what is shared, not a name.

Why: two ``magline run`` (a second terminal, the station screen beside a console) on one vehicle both
connected and both acquired the *same* readings — one PASSed, the other FAILed "reboot refused", a
verdict recorded against a unit nobody tested.  A run therefore holds, for as long as it lasts, a lock
on each thing two runs must not share: its station slot *in its results store* (two folders running the
embedded demo have two stores and both run; two runs of one station file share one), its vehicle link,
its power instrument, and the fixture's instruments (gimbal, coil, fluxgate) for the whole load.  The
operating system releases them if the process dies (``flock``), so a crashed station never leaves a
unit locked.  A second run is refused before anything is recorded, in a sentence that names what is
shared and the holder.  The locks are per computer (a directory under the system's temporary
folder); across computers the results store keeps which station holds which slot, and which serial
(``claimed_in_store``, :mod:`magline.core.results.claims`).
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import os
import re
import socket
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

from magline.core.faults import StationFault
from magline.core.links.addresses import names_a_vehicle_link
from magline.core.results.contract import ClaimsSlots
from magline.core.sequencer.periodic import every

if TYPE_CHECKING:
    from magline.core.station.schema import Product, Station

# a vehicle link: a MAVLink / serial address (a mock's "in-process" or a description is no shared vehicle)
# an instrument's address in a plugin's options: a VISA resource or a socket / serial address
ADDRESS = re.compile(r"^(TCPIP\d*::|GPIB\d*::|USB\d*::|ASRL|tcp:|tcpin:|udp:|udpin:|udpout:|serial:|/dev/)",
                     re.IGNORECASE)
VISA_SOCKET = re.compile(r"^TCPIP\d*::([^:]+)::(\d+)::SOCKET$", re.IGNORECASE)


class StationBusy(StationFault):
    """The slot or the vehicle is under test by another run: refused before any record exists."""


def lock_dir() -> Path:
    folder = Path(os.environ.get("MAGLINE_LOCK_DIR") or Path(tempfile.gettempdir()) / "magline-locks")
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def _file_name(key: str) -> str:
    """Readable and unique: a long store path cut short still names one file per key."""
    digest = hashlib.sha256(key.encode()).hexdigest()[:16]
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", key)[:120] + f"-{digest}.lock"


@contextlib.contextmanager
def holding(keys: list[Shared], holder: dict) -> Iterator[None]:
    """Hold every lock for the block, or raise :class:`StationBusy` naming what is shared and who holds
    the first one taken.  A key listed twice (two slots of one load on one supply) is taken once."""
    held: list[IO[str]] = []
    try:
        for key, what in {k.key: k.what for k in keys}.items():
            handle = (lock_dir() / _file_name(key)).open("a+", encoding="utf-8")
            try:
                fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                handle.seek(0)
                raise StationBusy(_refusal(what, handle.read())) from None
            handle.seek(0)
            handle.truncate()
            handle.write(json.dumps(holder))
            handle.flush()
            held.append(handle)
        yield
    finally:
        for handle in held:
            handle.seek(0)
            handle.truncate()
            fcntl.flock(handle, fcntl.LOCK_UN)
            handle.close()


@contextlib.contextmanager
def claimed_in_store(sink: object, holder: dict) -> Iterator[None]:
    """Hold the slot in the results store too, for the block: what tells two *computers* apart (the
    file lock above is per computer).  Refused: :class:`StationBusy` naming the holder, before any
    record.  The claim is refreshed while the unit runs, so a computer that dies loses it in minutes.
    A store without claims (a third-party sink) leaves the file lock alone to hold the slot."""
    if not isinstance(sink, ClaimsSlots):
        yield
        return
    claim = sink.claim_slot
    from magline.core.results.claims import HEARTBEAT_S

    refusal = claim(holder)
    if refusal is not None:
        raise StationBusy(refusal)
    def beat() -> None:
        with contextlib.suppress(StationFault):
            sink.touch_slot(holder)  # type: ignore[attr-defined]

    try:
        with every(HEARTBEAT_S, beat, "magline-slot-claim", join_s=5.0):
            yield
    finally:
        with contextlib.suppress(StationFault):
            sink.release_slot(holder)  # type: ignore[attr-defined]


def holder_of(serial: str, station_id: str, slot: str | None, folder: str = "", store: str = "") -> dict:
    """Who holds a lock, as a refusal names them: the unit, the station slot, where its files are
    (``folder``: the station file's folder) and its results store, the process and computer."""
    return {"serial": serial, "station": station_id, "slot": slot, "folder": folder, "store": store,
            "pid": os.getpid(), "host": socket.gethostname(), "since": datetime.now(UTC).isoformat(timespec="seconds")}


def _refusal(what: str, text: str) -> str:
    """The sentence refusing a run: what is shared, and who holds it.  Where the shared thing is the
    station's own slot, its holder is that same station: it is named once ("station demo-01 is busy
    testing serial …"), not twice."""
    holder = _describe(text)
    if holder.startswith(what + " is testing "):
        return f"{what} is busy testing {holder.removeprefix(what + ' is testing ')}"
    return f"{what} is busy: {holder}"


def _describe(text: str) -> str:
    try:
        h = json.loads(text)
    except ValueError:
        return "another magline process holds it"
    where = f"station {h.get('station')}" + (f" slot {h['slot']}" if h.get("slot") else "")
    files = ", ".join(part for part in (f"folder {h['folder']}" if h.get("folder") else "",
                                        f"results {h['store']}" if h.get("store") else "") if part)
    return (f"{where} is testing serial {h.get('serial')} ({files + '; ' if files else ''}pid {h.get('pid')} on "
            f"{h.get('host')}, since {h.get('since')}) — finish or abort that unit first")


@dataclass(frozen=True)
class Shared:
    """One thing two runs must not use at once: ``key`` names its lock file, ``what`` how a refusal
    names it ("the vehicle on tcp:127.0.0.1:5760")."""

    key: str
    what: str


def store_identity(station: Station, station_dir: Path | str) -> str:
    """The station's own results store as one string: a SQLite file's absolute path, a server's URL
    without its password, a plugin store's name and options.  Two station files naming the same
    store share it; two folders running the embedded demo each have their own."""
    entry = station.main_results
    if entry.sink == "sqlite":
        return str((Path(station_dir) / Path(entry.path).expanduser()).resolve())
    if entry.sink == "sql":
        from sqlalchemy.engine import make_url
        from sqlalchemy.exc import ArgumentError

        url = os.environ.get(entry.url_env or "", "")
        try:
            return make_url(url).render_as_string(hide_password=True)
        except ArgumentError:
            return f"the server in ${entry.url_env}"
    return f"{entry.sink} {json.dumps(entry.options, sort_keys=True, default=str)}"


def instrument_addresses(options: Any) -> list[str]:
    """Every instrument or vehicle address in a plugin's options (nested too), spelled one way: a VISA
    socket resource as its ``tcp:`` address (``TCPIP0::h::p::SOCKET`` is ``tcp:h:p``), another VISA
    resource without its board number."""
    found: list[str] = []
    if isinstance(options, dict):
        for value in options.values():
            found += instrument_addresses(value)
    elif isinstance(options, list | tuple):
        for value in options:
            found += instrument_addresses(value)
    elif isinstance(options, str) and ADDRESS.match(options.strip()):
        address = options.strip()
        socket_resource = VISA_SOCKET.match(address)
        if socket_resource:  # one instrument, however it is written: a VISA socket resource is its tcp: address
            address = f"tcp:{socket_resource[1]}:{socket_resource[2]}"
        found.append(re.sub(r"^(GPIB|USB|ASRL)\d+", r"\1", address, flags=re.IGNORECASE))
    return found


def unit_locks(station: Station, station_dir: Path | str, product: Product | None,
               slot: str | None) -> list[Shared]:
    """What one unit's run holds alone: its station slot in its results store, its vehicle link
    where it has one, and its own power instrument (a supply and channel)."""
    store = store_identity(station, station_dir)
    name = f"station {station.station.id}" + (f" slot {slot}" if slot else "")
    keys = [Shared(f"station-{station.station.id}-{slot or 'unit'}-{store}", name)]  # the holder names the store
    connection = product.connection.strip() if product is not None else ""
    if names_a_vehicle_link(connection):
        keys.append(Shared(f"link-{connection}", f"the vehicle on {connection}"))
    if product is not None:
        channel = product.power.options.get("channel")
        for address in instrument_addresses(product.power.options):
            at = address + (f" channel {channel}" if channel is not None else "")
            keys.append(Shared(f"instrument-{at}", f"the {product.power.method} power on {at}"))
    return keys


def fixture_locks(station: Station) -> list[Shared]:
    """What a whole load of the fixture holds: the instruments of its motion (a gimbal) and of its
    field source (a coil, its fluxgate).  Every slot of one load shares them; another load — another
    station file on the same gimbal — waits for them."""
    keys = []
    for role, options in (("motion", station.motion.options), ("field source", station.field_source.options)):
        kind = station.motion.type if role == "motion" else station.field_source.type
        keys += [Shared(f"instrument-{address}", f"the {kind} {role} on {address}")
                 for address in instrument_addresses(options)]
    return keys
