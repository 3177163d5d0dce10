""""The line now": one tile per station (per slot, on a station with slots) that recorded units lately —
what it tests now, its last units, its shift so far — from the results store alone, so any number of
stations and dashboards agree.

Why a station's *usual gap*: a line runs units at its own pace; a station is flagged silent when the time
since its last unit is several times the median gap between its recent units (and no unit is under test),
not after a fixed time that is long for one product and short for another.
"""

from __future__ import annotations

import itertools
import json
import statistics
from datetime import UTC, datetime, timedelta
from typing import TYPE_CHECKING, Any

from sqlalchemy import func, select

from magline.core.results.instants import stored_form
from magline.core.results.reading import shift_units
from magline.core.results.tables import runs, slot_claims, station_outbox

if TYPE_CHECKING:
    from sqlalchemy import Connection

    from magline.core.quality.trends import Shifts

RECENT = 6  # units on a tile
ACTIVE_DAYS = 14  # a station with no unit in this long has no tile
GAPS = 20  # the gaps a station's usual pace is the median of
SILENT_TIMES = 3.0  # silent: this many usual gaps since its last unit …
SILENT_LEAST_S = 600.0  # … and at least this long
CLAIM_FRESH_S = 120.0  # a slot claim refreshed within this is a unit under test (core/results/claims.py)


def line_now(conn: Connection, now: datetime, shifts: Shifts) -> dict[str, Any]:
    """Every recently active station's tile, by line and station id."""
    shift_start = shifts.start_of(now)
    since = stored_form(shift_start)
    active = stored_form(now - timedelta(days=ACTIVE_DAYS))
    stations = [(station_id, line) for station_id, line, started in _stations(conn) if started and started >= active]
    claims = conn.execute(select(slot_claims)).mappings().all()
    # what each forwarding station's outbox held when it last reached this store (none: it writes here directly)
    outboxes = {row["station_id"]: dict(row) for row in conn.execute(select(station_outbox)).mappings()}
    tiles = []
    for station_id, line in sorted(stations, key=lambda row: (str(row[1]), str(row[0]))):
        slots = _slots(conn, station_id, active)
        for slot in sorted(slots) or [None]:  # a station with slots: a tile per fixture position
            tiles.append(_tile(conn, station_id, line, slot, since, now, claims, outboxes))
    return {"shift_start": shift_start.isoformat(timespec="minutes"), "now": now.astimezone().isoformat(
        timespec="seconds"), "shift_word": "this shift" if shifts.starts else "today", "stations": tiles}


def _tile(conn: Connection, station_id: str, line: str | None, slot: str | None, since: str, now: datetime,
          claims: list, outboxes: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """One station's (or one of its slots') tile."""
    shift = shift_units(conn, station_id, since, RECENT, slot)
    chosen = (runs.c.station_id == station_id) & (runs.c.verdict != "running")
    if slot is not None:
        chosen = chosen & (runs.c.slot == slot)
    latest = conn.execute(select(runs.c.finished, runs.c.field_check).where(chosen & runs.c.finished.is_not(None))
                          .order_by(runs.c.started.desc()).limit(GAPS + 1)).all()
    finished = [row.finished for row in latest]
    # the field reference as the latest unit met it: the model and value, the live check's last
    field = json.loads(latest[0].field_check) if latest and latest[0].field_check else None
    testing = [{"slot": c["slot"], "serial": c["serial"], "since": c["since"]} for c in claims
               if c["station_id"] == station_id and (slot is None or c["slot"] == slot) and _fresh(c["heartbeat"], now)]
    return {"station_id": station_id, "slot": slot, "line": line, **shift,
            "per_hour": _per_hour(shift["units"], shift["first_started"], now), "testing": testing,
            **_pace(finished, now, bool(testing)), "field": field, "outbox": outboxes.get(station_id)}


def distinct(conn: Connection, column: Any, where: Any = None) -> list[Any]:
    """Every value of an indexed ``column`` (among the rows ``where`` chooses, the index leading with what it
    fixes), one index probe per value (a skip scan): a GROUP BY read every run of a million-run store."""
    found: list[Any] = []
    while True:
        query = select(func.min(column)) if where is None else select(func.min(column)).where(where)
        value = conn.execute(query.where(column > found[-1]) if found else query).scalar()
        if value is None:
            return found
        found.append(value)


def _stations(conn: Connection) -> list[tuple[str, str | None, str | None]]:
    """Every station id with its line and its latest unit's start (``runs_station_started``)."""
    found: list[tuple[str, str | None, str | None]] = []
    for station_id in distinct(conn, runs.c.station_id):
        latest = conn.execute(select(runs.c.line, runs.c.started).where(runs.c.station_id == station_id)
                              .order_by(runs.c.started.desc()).limit(1)).first()
        found.append((station_id, latest.line if latest else None, latest.started if latest else None))
    return found


def _slots(conn: Connection, station_id: str, active: str) -> list[str]:
    """The station's slots with a unit begun since ``active``: every slot it ever had, one probe each of
    ``runs_station_slot_started`` (a skip scan), then one probe each for a unit since ``active``.  Why not one
    DISTINCT: it read the station's fortnight of runs, half a second over ten stations of a million-run store."""
    ever = distinct(conn, runs.c.slot, (runs.c.station_id == station_id) & runs.c.slot.is_not(None))
    return [slot for slot in ever if conn.execute(
        select(runs.c.id).where((runs.c.station_id == station_id) & (runs.c.slot == slot) & (runs.c.started >= active))
        .limit(1)).first() is not None]


def _fresh(heartbeat: str | None, now: datetime) -> bool:
    if not heartbeat:
        return False
    return (now - datetime.fromisoformat(heartbeat)).total_seconds() <= CLAIM_FRESH_S


def _per_hour(units: int, first_started: str | None, now: datetime) -> float | None:
    """Units an hour since the shift's first unit began (an idle start of shift is not the line's pace);
    None below two units."""
    if units < 2 or not first_started:
        return None
    hours = max((now - datetime.fromisoformat(first_started)).total_seconds(), 60.0) / 3600.0
    return units / hours


def _pace(finished: list[str], now: datetime, testing: bool) -> dict[str, Any]:
    """The station's last unit, its usual gap between units, and whether it is silent beyond it."""
    if not finished:
        return {"last_finished": None, "usual_gap_s": None, "silent": False, "silent_s": None}
    times = [datetime.fromisoformat(f) for f in finished]
    gaps = [(a - b).total_seconds() for a, b in itertools.pairwise(times) if a > b]
    usual = statistics.median(gaps) if gaps else None
    since_last = (now - times[0]).total_seconds()
    silent = usual is not None and not testing and since_last > max(SILENT_TIMES * usual, SILENT_LEAST_S)
    return {"last_finished": times[0].astimezone(UTC).isoformat(timespec="seconds"), "usual_gap_s": usual,
            "silent": silent, "silent_s": since_last if silent else None}


RECENT_RUNS = 200  # the latest runs whose ends the live pages watch (far more than a line runs at once)


def store_version(conn: Connection) -> tuple[Any, ...]:
    """What changes when any station records a unit (or starts one): the dashboard's live pages follow it.
    The latest runs by id with their verdicts and ends, and the slot claims — a few index reads, never a
    count of runs."""
    latest = tuple(conn.execute(select(runs.c.id, runs.c.verdict, runs.c.finished).order_by(runs.c.id.desc())
                                .limit(RECENT_RUNS)).all())
    return latest + tuple(conn.execute(select(slot_claims.c.station_id, slot_claims.c.slot, slot_claims.c.serial)
                                       .order_by(slot_claims.c.station_id, slot_claims.c.slot)).all()) \
        + tuple(conn.execute(select(station_outbox).order_by(station_outbox.c.station_id)).all())
