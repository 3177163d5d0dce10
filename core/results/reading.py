"""Reading records back: one whole run (``magline show``) and filtered, streamed exports
(``magline export``) — the same queries on every engine.

Why streamed: a factory store holds millions of runs; an export walks them in batches
(``yield_per``) and fetches each batch's measurements with one query, so memory stays constant
however many rows are written.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import TYPE_CHECKING, Any

from sqlalchemy import func, select

from magline.core.fit.samples_csv import RawSamples
from magline.core.measurements import CATALOGUE
from magline.core.results import raw_blob
from magline.core.results.instants import stored_form
from magline.core.results.tables import attempt_streams, attempts, measurements, params, phases, runs

if TYPE_CHECKING:
    from sqlalchemy import Connection

BATCH = 500
LONGEST_UNIT = timedelta(days=1)  # longer than any unit's record spans from its start to its end
JSON_COLUMNS = ("unit_info", "calibration", "persistence", "left_changed", "unverified_params", "review")


@dataclass(frozen=True)
class RunFilter:
    since: str | None = None  # ISO time: runs started at or after
    until: str | None = None  # ISO time: runs started before
    part: str | None = None
    station_id: str | None = None
    line: str | None = None
    verdict: str | None = None
    serial: str | None = None  # one unit's runs, whatever the case it is typed in (spaces around it ignored)
    operator: str | None = None
    verdicts: tuple[str, ...] | None = None  # any of these verdicts (judged units: pass and fail)

    def apply(self, query: Any) -> Any:
        if self.serial is not None:
            query = query.where(func.upper(runs.c.serial) == self.serial.strip().upper())
        if self.verdicts is not None:
            query = query.where(runs.c.verdict.in_(self.verdicts))
        for column, value, op in ((runs.c.started, self.since, "ge"), (runs.c.started, self.until, "lt"),
                                  (runs.c.part, self.part, "eq"), (runs.c.station_id, self.station_id, "eq"),
                                  (runs.c.line, self.line, "eq"), (runs.c.operator, self.operator, "eq"),
                                  (runs.c.verdict, self.verdict, "eq")):
            if value is not None:
                query = query.where({"ge": column >= value, "lt": column < value, "eq": column == value}[op])
        return query


def _run_row(row: Any) -> dict[str, Any]:
    out = dict(row._mapping)
    for key in JSON_COLUMNS:
        if out.get(key):
            out[key] = json.loads(out[key])
    return out


def find_run(conn: Connection, run: str) -> dict[str, Any] | None:
    """The whole record of a run, by its local id or its UUID."""
    query = select(runs).where(runs.c.run_uuid == run) if not run.isdigit() else select(runs).where(
        runs.c.id == int(run))
    row = conn.execute(query).first()
    if row is None:
        return None
    out = _run_row(row)
    rid = out["id"]
    out["phases"] = [dict(r._mapping) for r in conn.execute(
        select(phases).where(phases.c.run_id == rid).order_by(phases.c.seq))]
    out["attempts"] = run_attempts(conn, rid)
    out["measurements"] = [dict(r._mapping) for r in conn.execute(
        select(measurements).where(measurements.c.run_id == rid))]
    out["params"] = {}
    for r in conn.execute(select(params).where(params.c.run_id == rid)):
        out["params"].setdefault(r.stage, {})[r.name] = r.value
    return out


def same_serial(conn: Connection, wanted: str) -> Any:
    """The condition that finds a unit's runs whatever the case its serial is typed in: the serial as
    typed where the store holds it so (a part with ``serial_case: exact`` may hold ``sn-a`` and ``SN-A``
    as two units), else case-folded (``sn-lower-01`` finds ``SN-LOWER-01``).  Spaces around it ignored."""
    wanted = wanted.strip()
    if conn.execute(select(runs.c.id).where(runs.c.serial == wanted).limit(1)).first() is not None:
        return runs.c.serial == wanted
    return func.upper(runs.c.serial) == wanted.upper()


class RunNotFound(LookupError):
    """No run has that id or UUID and no unit that serial: the reading commands say so and exit 1."""

    def __init__(self, wanted: str, where: str) -> None:
        super().__init__(f"no run or serial {wanted.strip()!r} in {where} (magline history lists a unit's runs)")


def find_run_or_serial(conn: Connection, wanted: str) -> dict[str, Any] | None:
    """A run by local id or UUID, else the latest run of a serial (spaces around it and its case ignored)."""
    wanted = wanted.strip()
    found = find_run(conn, wanted)
    if found is None:
        latest = conn.execute(select(runs.c.id).where(same_serial(conn, wanted)).order_by(runs.c.id.desc())).first()
        found = find_run(conn, str(latest[0])) if latest is not None else None
    return found


_PAIRED = ("heading_agreement_median_deg", "heading_agreement_max_deg")
_PER_SENSOR = (*sorted(n for n in CATALOGUE if n not in _PAIRED), "residual_ut.mean", "residual_ut.std",
               "residual_ut.ptp")
# the primary magnetometer's names, then the second's and the third's (``mag2.…``), then every pair's:
# a CSV's columns are fixed before the first row, so every sensor of a three-compass unit has its own
NUMERIC_NAMES = (*_PER_SENSOR, *(f"{p}.{n}" for p in ("mag2", "mag3") for n in _PER_SENSOR),
                 *(f"{pair}.{n}" for pair in ("mag1-mag2", "mag1-mag3", "mag2-mag3") for n in _PAIRED))
RUN_COLUMNS = ("run_uuid", "id", "serial", "part", "station_id", "line", "operator", "software_version",
               "limit_hash", "started", "finished", "verdict", "cause")


def measurement_names(conn: Connection, where: RunFilter) -> set[str]:
    """The numeric measurements the matching runs hold (an export's columns: only the compasses and
    pairs these units have)."""
    chosen = where.apply(select(runs.c.id)).subquery("chosen")
    query = select(measurements.c.name).distinct().where(
        measurements.c.run_id.in_(select(chosen.c.id)) & (measurements.c.kind == "numeric"))
    return {name for (name,) in conn.execute(query)}


def export_runs(conn: Connection, where: RunFilter, with_params: bool = False) -> Iterator[dict[str, Any]]:
    """Every matching run, oldest first, with its numeric measurements (``{name: {value, verdict}}``)
    and, ``with_params``, the parameters written to the unit (``params_written``: name → value)."""
    query = where.apply(select(runs).order_by(runs.c.id))
    result = conn.execution_options(stream_results=True, yield_per=BATCH).execute(query)
    for batch in result.partitions(BATCH):
        found = [_run_row(r) for r in batch]
        ids = [r["id"] for r in found]
        written: dict[int, dict[str, float]] = {i: {} for i in ids}
        if with_params:
            for row in conn.execute(select(params.c.run_id, params.c.name, params.c.value).where(
                    params.c.run_id.in_(ids) & (params.c.stage == "written"))):
                written[row.run_id][row.name] = row.value
        numeric: dict[int, dict[str, dict]] = {i: {} for i in ids}
        for m in conn.execute(select(measurements.c.run_id, measurements.c.name, measurements.c.value,
                                     measurements.c.unit, measurements.c.low, measurements.c.high,
                                     measurements.c.verdict)
                              .where(measurements.c.run_id.in_(ids) & (measurements.c.kind == "numeric"))):
            numeric[m.run_id][m.name] = {"value": m.value, "unit": m.unit, "low": m.low, "high": m.high,
                                         "verdict": m.verdict}
        for run in found:
            run["measurements"] = numeric[run["id"]]
            if with_params:
                run["params_written"] = written[run["id"]]
            yield run


def run_attempts(conn: Connection, run_id: int, with_samples: bool = False) -> list[dict[str, Any]]:
    """A run's acquisition attempts, in order; with ``with_samples`` each carries its raw readings
    (``raw``: :class:`RawSamples`, None when the attempt stored none; ``samples`` stays their count)."""
    columns = [c for c in attempts.c if c.name != "raw"] + ([attempts.c.raw] if with_samples else [])
    found = []
    for r in conn.execute(select(*columns).where(attempts.c.run_id == run_id).order_by(attempts.c.attempt)):
        row = dict(r._mapping)
        if with_samples:
            blob = row["raw"]
            row["raw"] = raw_blob.decode(bytes(blob)) if blob is not None else None
        found.append(row)
    return found


def attempt_sensor_streams(conn: Connection, run_id: int, attempt: int) -> dict[int, RawSamples]:
    """The readings of an attempt's other magnetometers (``attempt_streams`` rows ``mag:<device id>``),
    by device id, in the order they were stored."""
    found: dict[int, RawSamples] = {}
    rows = conn.execute(select(attempt_streams.c.stream, attempt_streams.c.raw).where(
        (attempt_streams.c.run_id == run_id) & (attempt_streams.c.attempt == attempt)))
    for stream, blob in rows:
        if stream.startswith("mag:") and blob is not None:
            found[int(stream.removeprefix("mag:"))] = raw_blob.decode(bytes(blob))
    return found


def serial_attempts(conn: Connection, serial: str) -> list[dict[str, Any]]:
    """Every stored attempt of a unit, oldest run first, with its raw readings — what a quality
    engineer pulls to re-fit a unit."""
    found = []
    for (rid,) in conn.execute(select(runs.c.id).where(same_serial(conn, serial)).order_by(runs.c.id)):
        found += [{"run_id": rid, **a} for a in run_attempts(conn, rid, with_samples=True)]
    return found


def params_by_stage(conn: Any, run_ids: list[int]) -> dict[int, dict[str, dict[str, float]]]:
    """Each run's parameters by stage ("before", "written", …) for ``run_ids`` (read in chunks)."""
    from magline.core.results.tables import params

    out: dict[int, dict[str, dict[str, float]]] = {}
    for start in range(0, len(run_ids), 500):
        chunk = run_ids[start:start + 500]
        for row in conn.execute(select(params.c.run_id, params.c.stage, params.c.name, params.c.value)
                                .where(params.c.run_id.in_(chunk))):
            out.setdefault(int(row.run_id), {}).setdefault(str(row.stage), {})[str(row.name)] = float(row.value)
    return out


def shift_units(conn: Connection, station_id: str, since: str, recent: int, slot: str | None = None) -> dict[str, Any]:
    """A station's units since ``since`` (stored form), as its screen shows them: how many ran, the
    first-pass yield (a serial's first run here, judged PASS or FAIL), and the latest ``recent``, newest
    first, each with the verdict as shown (a PASS with a flagged measurement is REVIEW).

    Why from the store: every screen of the station, and one restarted mid-shift, counts the same units.
    A unit belongs to the shift it was finished in (one started before the shift began and judged after
    it is this shift's): the operator who just saw its verdict sees it counted.  ``slot``: that fixture
    position's units only.

    Only units begun within :data:`LONGEST_UNIT` before ``since`` are looked at: that bounds the read to the
    station's index range of the shift (a million-run store read every run of the station otherwise, 70 ms a
    station), and no unit's record spans a day."""
    ended = func.coalesce(runs.c.finished, runs.c.started)  # a record without its end: when it began
    began_by = stored_form(datetime.fromisoformat(since) - LONGEST_UNIT)
    chosen = ((runs.c.station_id == station_id) & (runs.c.started >= began_by) & (ended >= since)
              & (runs.c.verdict != "running"))
    if slot is not None:
        chosen = chosen & (runs.c.slot == slot)
    found = conn.execute(select(runs.c.id, runs.c.serial, runs.c.part, runs.c.verdict, runs.c.slot, runs.c.finished,
                                runs.c.review, runs.c.started).where(chosen).order_by(runs.c.id)).all()
    first: dict[str, str] = {}
    for row in found:
        first.setdefault(row.serial, row.verdict)
    judged = [v for v in first.values() if v in ("pass", "fail")]
    latest = found[-recent:][::-1] if recent else []
    flagged = {r.run_id for r in conn.execute(
        select(measurements.c.run_id).where(measurements.c.run_id.in_([row.id for row in latest])
                                            & measurements.c.verdict.in_(("review", "fail"))).distinct())}

    def shown(row: Any) -> str:
        review = bool(row.review and json.loads(row.review))
        return "review" if row.verdict == "pass" and (review or row.id in flagged) else row.verdict

    passed = sum(v == "pass" for v in judged)
    return {"units": len(found), "first_started": min((row.started for row in found), default=None),
            "first_pass": passed, "judged": len(judged),
            "fpy": passed / len(judged) if judged else None,
            "recent": [{"serial": row.serial, "part": row.part, "verdict": shown(row), "slot": row.slot,
                        "finished": row.finished} for row in latest]}
