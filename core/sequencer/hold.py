"""One run per vehicle and per station slot, held with operating-system file locks.

Why: two ``magline run`` (a second terminal, the station screen beside a console) on one vehicle both
connected and both acquired the *same* readings — one PASSed, the other FAILed "reboot refused", a
verdict recorded against a unit nobody tested.  A run therefore holds, for as long as it lasts, a lock
on its station slot and one on its vehicle link; the operating system releases them if the process
dies (``flock``), so a crashed station never leaves a unit locked.  A second run is refused before
anything is recorded, in a sentence that names the holder.  The locks are per computer (a directory
under the system's temporary folder); across computers the results store keeps which station holds
which slot (``claimed_in_store``, :mod:`magline.core.results.claims`).
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import re
import socket
import tempfile
from collections.abc import Iterator
from datetime import UTC, datetime
from pathlib import Path
from typing import IO

from magline.core.faults import StationFault
from magline.core.periodic import every

# a vehicle link: a MAVLink / serial address (a mock's "in-process" or a description is no shared vehicle)
VEHICLE_LINK = re.compile(r"^(tcp|tcpin|tcpout|udp|udpin|udpout|serial|com|/dev/)", re.IGNORECASE)


class StationBusy(StationFault):
    """The slot or the vehicle is under test by another run: refused before any record exists."""


def lock_dir() -> Path:
    folder = Path(os.environ.get("MAGLINE_LOCK_DIR") or Path(tempfile.gettempdir()) / "magline-locks")
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def _file_name(key: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", key)[:200] + ".lock"


@contextlib.contextmanager
def holding(keys: list[tuple[str, str]], holder: dict) -> Iterator[None]:
    """Hold every ``(key, what)`` lock (``what`` is how the refusal names it) for the block, or raise
    :class:`StationBusy` naming who holds the first one taken."""
    held: list[IO[str]] = []
    try:
        for key, what in keys:
            handle = (lock_dir() / _file_name(key)).open("a+", encoding="utf-8")
            try:
                fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                handle.seek(0)
                raise StationBusy(f"{what} is busy: {_describe(handle.read())}") from None
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
    claim = getattr(sink, "claim_slot", None)
    if claim is None:
        yield
        return
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


def holder_of(serial: str, station_id: str, slot: str | None) -> dict:
    return {"serial": serial, "station": station_id, "slot": slot, "pid": os.getpid(), "host": socket.gethostname(),
            "since": datetime.now(UTC).isoformat(timespec="seconds")}


def _describe(text: str) -> str:
    try:
        h = json.loads(text)
    except ValueError:
        return "another magline process holds it"
    where = f"station {h.get('station')}" + (f" slot {h['slot']}" if h.get("slot") else "")
    return (f"{where} is testing serial {h.get('serial')} (pid {h.get('pid')} on {h.get('host')}, since "
            f"{h.get('since')}) — finish or abort that unit first")


def run_locks(station_id: str, slot: str | None, connection: str) -> list[tuple[str, str]]:
    """The locks a unit's run holds: its station slot, and its vehicle link where it has one."""
    keys = [(f"station-{station_id}-{slot or 'unit'}",
             f"{station_id}" + (f" slot {slot}" if slot else ""))]
    if VEHICLE_LINK.match(connection.strip()):
        keys.append((f"link-{connection.strip()}", f"the vehicle on {connection.strip()}"))
    return keys
