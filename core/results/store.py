"""A results store on any SQLAlchemy engine: what the ``sqlite`` (embedded) and ``sql`` (server)
sinks share.

Why incremental writes: the run row is written when the unit is identified (``running``, with its
writer's host:pid), each attempt's raw data the moment the attempt ends, everything else when the
run finishes — so a crash later in the run loses nothing, and a run whose writer died is found
(``incomplete``) the next time the store is opened.
"""

from __future__ import annotations

import json
import uuid
from collections.abc import Sequence
from dataclasses import asdict
from typing import TYPE_CHECKING, Any

from sqlalchemy import select, text, update
from sqlalchemy.exc import SQLAlchemyError

from magline.core.faults import StationFault
from magline.core.measurements import Array, Json, Numeric
from magline.core.results import claims, raw_blob, schema_version
from magline.core.results.processes import alive, owner
from magline.core.results.reading import same_serial
from magline.core.results.series import load_series
from magline.core.results.tables import (
    attachments,
    attempt_streams,
    attempts,
    measurements,
    params,
    phases,
    runs,
    station_outbox,
)

if TYPE_CHECKING:
    from sqlalchemy import Engine

    from magline.core.record import AttemptRecord, RunRecord
    from magline.core.results.reading import RunFilter
    from magline.core.results.series import RunSeries

RUNNING = "running"


RUNS_CHANNEL = "magline_runs"  # PostgreSQL's NOTIFY channel: a run begun, recorded or a slot claimed


class SqlStore:
    """``begin`` / ``save_attempt`` / ``finish`` / ``history`` / ``location`` on one engine."""

    def __init__(self, engine: Engine, where: str) -> None:
        self.engine = engine
        self.where = where  # how the store is named to people (a file, a server without its password)
        try:
            self.revision = schema_version.upgrade(engine, where)
        except SQLAlchemyError as exc:
            raise StationFault(f"results store {where}: {reason(exc)}") from exc
        self.mark_incomplete()

    def close(self) -> None:
        self.engine.dispose()

    @property
    def record_engine(self) -> Engine:
        """Where the record just written is (for the station's own unit reports)."""
        return self.engine

    def location(self, record: RunRecord) -> str:
        return f"{self.where} run {record.run_id}"

    def _write(self, what: str, fn: Any) -> Any:
        try:
            with self.engine.begin() as conn:
                done = fn(conn)
                if conn.dialect.name == "postgresql":  # delivered at commit: the dashboards' pages wake
                    conn.execute(text(f"NOTIFY {RUNS_CHANNEL}"))
                return done
        except SQLAlchemyError as exc:
            raise StationFault(f"results store {self.where}: {what} failed: {reason(exc)}") from exc

    # -------------------------------------------------------------- what a station's outbox holds
    def report_outbox(self, reports: Sequence[dict[str, Any]]) -> None:
        """What each station's outbox still holds (``station_id``, ``reported``, ``queued``, ``oldest``),
        replacing its last report: the line's dashboard shows it on the station's tile."""

        def write(conn: Any) -> None:
            for report in reports:
                conn.execute(station_outbox.delete().where(station_outbox.c.station_id == report["station_id"]))
                conn.execute(station_outbox.insert().values(**report))

        self._write("reporting the outbox", write)

    # -------------------------------------------------------------- which station holds which slot
    def claim_slot(self, holder: dict) -> str | None:
        """Claim the holder's (station, slot) here; the sentence refusing it when another live holder
        has it (see :mod:`magline.core.results.claims`)."""
        return self._write("claiming the slot", lambda conn: claims.claim(conn, holder))

    def touch_slot(self, holder: dict) -> None:
        self._write("refreshing the slot's claim", lambda conn: claims.heartbeat(conn, holder))

    def release_slot(self, holder: dict) -> None:
        self._write("releasing the slot", lambda conn: claims.release(conn, holder))

    def slots_held(self) -> list[dict[str, Any]]:
        try:
            with self.engine.connect() as conn:
                return claims.held(conn)
        except SQLAlchemyError as exc:
            raise StationFault(f"results store {self.where}: reading the slot claims failed: {reason(exc)}") from exc

    def mark_incomplete(self) -> int:
        """Runs left ``running`` by a process that no longer exists become ``incomplete``."""
        def mark(conn: Any) -> int:
            stale = [rid for rid, writer in conn.execute(select(runs.c.id, runs.c.owner).where(
                runs.c.verdict == RUNNING)) if not alive(writer)]
            for rid in stale:
                conn.execute(update(runs).where(runs.c.id == rid).values(
                    verdict="incomplete", cause="the station process ended before the run finished"))
            return len(stale)
        return self._write("marking interrupted runs", mark)

    def begin(self, record: RunRecord) -> None:
        def insert(conn: Any) -> int:
            return conn.execute(runs.insert().values(
                run_uuid=str(uuid.uuid4()), serial=record.serial, part=record.part, station_id=record.station_id,
                line=record.line, operator=record.operator, software_version=record.software_version,
                limit_hash=record.limit_hash, started=record.started, verdict=RUNNING, owner=owner(),
                earlier_runs=record.earlier_runs, station_hash=record.station_hash, slot=record.slot,
                slot_group=record.slot_group)).inserted_primary_key[0]
        record.run_id = self._write("starting the run's record", insert)

    def save_attempt(self, record: RunRecord, attempt: AttemptRecord) -> None:
        if record.run_id is None:
            self.begin(record)
        streams = [{"run_id": record.run_id, "attempt": attempt.attempt, "stream": f"mag:{device_id}",
                    "samples": len(samples), "raw": raw_blob.encode(samples)}
                   for device_id, samples in attempt.more.items()]
        if attempt.imu is not None:
            streams.append({"run_id": record.run_id, "attempt": attempt.attempt, "stream": "imu",
                            "samples": len(attempt.imu), "raw": raw_blob.encode_imu(attempt.imu)})

        def write(conn: Any) -> None:
            conn.execute(attempts.insert().values(
                run_id=record.run_id, attempt=attempt.attempt, samples=attempt.samples, coverage=attempt.coverage,
                target=attempt.target, accepted=int(attempt.accepted), raw=raw_blob.encode(attempt.raw),
                refused=attempt.refused, repeats=attempt.repeats, sensor_rate_hz=attempt.sensor_rate_hz,
                stopped=attempt.stopped, tumble_s=attempt.tumble_s,
                predicted=json.dumps(attempt.predicted) if attempt.predicted else None))
            _insert(conn, attempt_streams, streams)

        self._write("storing the attempt's raw data", write)

    def finish(self, record: RunRecord) -> None:
        if record.run_id is None:
            self.begin(record)
        rid = record.run_id

        def write(conn: Any) -> None:
            conn.execute(update(runs).where(runs.c.id == rid).values(
                finished=record.finished, verdict=str(record.verdict), cause=record.cause,
                unit_info=json.dumps(record.unit_info),
                calibration=json.dumps(record.calibration) if record.calibration else None,
                persistence=json.dumps(record.persistence), aborted_phase=record.aborted_phase,
                reference_field_ut=record.reference_field_ut,
                field_check=json.dumps(record.field_check) if record.field_check else None,
                review=json.dumps(record.review) if record.review else None, review_note=record.review_note or None,
                left_changed=json.dumps(record.left_changed) if record.left_changed else None,
                unverified_params=json.dumps(record.unverified_params) if record.unverified_params else None))
            # the fit may refuse an attempt after its raw data were saved: final verdicts per attempt
            for a in record.attempts:
                conn.execute(update(attempts).where((attempts.c.run_id == rid) & (attempts.c.attempt == a.attempt))
                             .values(accepted=int(a.accepted), refused=a.refused))
            rows = [{"run_id": rid, "seq": i, "name": p.name, "outcome": str(p.outcome), "duration_s": p.duration_s,
                     "message": p.message, "log": "\n".join(p.log)} for i, p in enumerate(record.phases)]
            _insert(conn, phases, rows)
            _insert(conn, measurements, [_measurement_row(rid, m) for m in _flatten(record.measurements)])
            _insert(conn, params, [{"run_id": rid, "stage": stage, "name": k, "value": float(v)}
                                   for stage, values in (("before", record.params_before),
                                                         ("written", record.params_written),
                                                         ("echoed", record.params_echoed),
                                                         ("read_back", record.params_read_back))
                                   for k, v in values.items()])
            _insert(conn, attachments, [{"run_id": rid, "name": a.name, "mime": a.mime, "content": a.content}
                                        for a in record.attachments])
        self._write("storing the run's record", write)

    def series(self, where: RunFilter, last: int | None = None, names: Sequence[str] | None = None,
               with_attempts: bool = False, with_limits: bool = True, first: int | None = None) -> RunSeries:
        """The latest runs matching ``where`` (``first``: the oldest that many) with their numeric
        measurements as arrays (statistics)."""
        try:
            with self.engine.connect() as conn:
                found = load_series(conn, where, last, names, with_attempts, with_limits, first)
        except SQLAlchemyError as exc:
            raise StationFault(f"results store {self.where}: reading the process history failed: "
                               f"{reason(exc)}") from exc
        found.source = self.where
        return found

    def history(self, serial: str) -> list[dict[str, Any]]:
        """Every run of a unit (whatever the case its serial is typed in), oldest first, with attempts and
        failed measurements."""
        try:
            with self.engine.connect() as conn:
                found = [dict(r._mapping) for r in conn.execute(
                    select(runs.c.id, runs.c.run_uuid, runs.c.serial, runs.c.part, runs.c.station_id, runs.c.line,
                           runs.c.operator, runs.c.started, runs.c.finished, runs.c.verdict, runs.c.cause,
                           runs.c.limit_hash, runs.c.calibration, runs.c.aborted_phase)
                    .where(same_serial(conn, serial)).order_by(runs.c.id))]
                for run in found:
                    run["attempts"] = [dict(r._mapping) for r in conn.execute(
                        select(attempts.c.attempt, attempts.c.samples, attempts.c.coverage, attempts.c.accepted,
                               attempts.c.refused).where(attempts.c.run_id == run["id"]).order_by(attempts.c.attempt))]
                    run["failed"] = [dict(r._mapping) for r in conn.execute(
                        select(measurements.c.name, measurements.c.value, measurements.c.unit, measurements.c.low,
                               measurements.c.high).where((measurements.c.run_id == run["id"])
                                                          & (measurements.c.verdict == "fail")))]
                    run["calibration"] = json.loads(run["calibration"]) if run["calibration"] else None
        except SQLAlchemyError as exc:
            raise StationFault(f"results store {self.where}: reading the history failed: {reason(exc)}") from exc
        return found


def _insert(conn: Any, table: Any, rows: list[dict]) -> None:
    if rows:
        conn.execute(table.insert(), rows)


def reason(exc: Exception) -> str:
    """The driver's own words, without SQLAlchemy's statement dump (which may be long)."""
    return str(getattr(exc, "orig", None) or exc).splitlines()[0]


def _flatten(items: list) -> Any:
    for m in items:
        yield m
        if isinstance(m, Array):
            yield from m.aggregations


def _measurement_row(rid: int, m: Any) -> dict:
    row = {"run_id": rid, "name": getattr(m, "name", "?"), "kind": "other", "value": None, "unit": None,
           "low": None, "high": None, "verdict": None, "data": None}
    if isinstance(m, Numeric):
        row.update(kind="numeric", value=m.value, unit=m.unit, low=m.low, high=m.high, verdict=str(m.verdict))
    elif isinstance(m, Array):
        row.update(kind="array", unit=m.unit, data=json.dumps(m.values))
    elif isinstance(m, Json):
        row.update(kind="json", data=json.dumps(m.data))
    else:
        row.update(data=json.dumps(asdict(m)))
    return row
