"""Which station holds which slot, kept in the results store: one run per slot across computers.

Why in the store: the operating-system lock (``core/sequencer/hold.py``) stops a second run on the same
computer; two computers given the same station file and slot — a copied configuration, a spare PC
switched on — share only the results store.  A run therefore claims its ``(station, slot)`` row there
before anything is recorded and gives it back at the end; a claim held by another computer or another
live process refuses the run in a sentence naming the holder.  A claim also names its serial, once in
the whole store: a label scanned for a unit already under test in another slot or on another station
sharing the store is refused the same way (one serial is one unit).

A computer that died never gives its claim back: every holder refreshes its row (``heartbeat``) while
its unit runs, and a row not refreshed for ``STALE_S`` is taken over.  A process of this computer that
no longer exists is taken over at once (the OS lock has gone with it).
"""

from __future__ import annotations

import socket
from datetime import UTC, datetime, timedelta
from typing import Any

from sqlalchemy import and_, delete, select, update
from sqlalchemy.exc import IntegrityError

from magline.core.results.processes import alive
from magline.core.results.tables import slot_claims

STALE_S = 120.0  # a claim not refreshed this long belongs to a computer that is gone
HEARTBEAT_S = 30.0  # how often a holder refreshes its claim


def _now() -> datetime:
    return datetime.now(UTC)


def _iso(t: datetime) -> str:
    return t.isoformat(timespec="seconds")


def describe(row: Any) -> str:
    where = f"station {row.station_id}" + (f" slot {row.slot}" if row.slot else "")
    return (f"{where} is testing serial {row.serial} on {row.host} (pid {row.pid}, since {row.since}, "
            f"seen {row.heartbeat}) — finish or abort that unit there first")


def describe_serial(row: Any) -> str:
    where = f"station {row.station_id}" + (f" slot {row.slot}" if row.slot else "")
    return (f"{row.serial} is under test on {where} ({row.host}, pid {row.pid}, since {row.since}): one serial "
            "is one unit — scan this unit's own label, or finish that test first")


def holder_key(holder: Any) -> dict[str, Any]:
    """A holder's (station, slot), from a holder dictionary or a claim's row."""
    if "station_id" in holder:
        return {"station_id": str(holder["station_id"]), "slot": str(holder.get("slot") or "")}
    return {"station_id": str(holder["station"]), "slot": str(holder.get("slot") or "")}


def claim(conn: Any, holder: dict) -> str | None:
    """Claim the holder's slot in one transaction; the sentence that refuses it when another live holder
    has it (None: claimed)."""
    key = holder_key(holder)
    serial = str(holder["serial"])
    where = and_(slot_claims.c.station_id == key["station_id"], slot_claims.c.slot == key["slot"])
    row = conn.execute(select(slot_claims).where(where)).first()
    now = _now()
    if row is not None and not _ours(row, holder) and not _gone(row, now):
        return describe(row)
    elsewhere = conn.execute(select(slot_claims).where(slot_claims.c.serial == serial)).first()
    if elsewhere is not None and holder_key(elsewhere._mapping) != key:
        if not _gone(elsewhere, now):  # the same unit in another slot, or on another station of this store
            return describe_serial(elsewhere)
        conn.execute(delete(slot_claims).where(and_(slot_claims.c.station_id == elsewhere.station_id,
                                                    slot_claims.c.slot == elsewhere.slot)))
    conn.execute(delete(slot_claims).where(where))
    try:
        with conn.begin_nested():
            conn.execute(slot_claims.insert().values(
                **key, host=str(holder["host"]), pid=int(holder["pid"]), serial=serial,
                since=str(holder.get("since") or _iso(now)), heartbeat=_iso(now)))
    except IntegrityError:  # another computer claimed the slot or the serial between our read and our write
        row = conn.execute(select(slot_claims).where(where)).first()
        if row is not None:
            return describe(row)
        row = conn.execute(select(slot_claims).where(slot_claims.c.serial == serial)).first()
        return describe_serial(row) if row is not None else "another station claimed it at the same moment"
    return None


def heartbeat(conn: Any, holder: dict) -> None:
    key = holder_key(holder)
    conn.execute(update(slot_claims).where(and_(
        slot_claims.c.station_id == key["station_id"], slot_claims.c.slot == key["slot"],
        slot_claims.c.host == str(holder["host"]), slot_claims.c.pid == int(holder["pid"]))).values(
        heartbeat=_iso(_now())))


def release(conn: Any, holder: dict) -> None:
    key = holder_key(holder)
    conn.execute(delete(slot_claims).where(and_(
        slot_claims.c.station_id == key["station_id"], slot_claims.c.slot == key["slot"],
        slot_claims.c.host == str(holder["host"]), slot_claims.c.pid == int(holder["pid"]))))


def held(conn: Any) -> list[dict[str, Any]]:
    """Every live claim: which station holds which slot, for ``magline slots``."""
    now = _now()
    return [dict(r._mapping) for r in conn.execute(select(slot_claims).order_by(
        slot_claims.c.station_id, slot_claims.c.slot)) if not _gone(r, now)]


def _ours(row: Any, holder: dict) -> bool:
    return row.host == str(holder["host"]) and int(row.pid) == int(holder["pid"])


def _gone(row: Any, now: datetime) -> bool:
    """A holder that will never give the slot back: silent past ``STALE_S``, or a process of this
    computer that no longer exists."""
    try:
        seen = datetime.fromisoformat(row.heartbeat)
    except (TypeError, ValueError):
        return True
    if now - seen > timedelta(seconds=STALE_S):
        return True
    return row.host == socket.gethostname() and not alive(f"{row.host}:{row.pid}")
