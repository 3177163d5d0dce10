"""The default results store: one SQLite file per station, named in the station file.

Why SQLite: a real database with transactions on a line PC, no server, readable by any quality
tool.  Attempts (raw samples) are committed the moment they exist, so a crash later in the run
loses nothing.  Relative paths are resolved against the station file's directory (the embedded
demo's: the directory magline runs in).  A run is written as ``running`` with its writer
(host:pid); a store opened later marks the runs of writers that no longer exist ``incomplete``.
"""

from __future__ import annotations

import json
import os
import socket
import sqlite3
from dataclasses import asdict
from pathlib import Path
from typing import Any

from magline.core.faults import StationFault
from magline.core.measurements import Array, Json, Numeric
from magline.core.plugins import hookimpl
from magline.core.record import AttemptRecord, RunRecord

SCHEMA = """
CREATE TABLE IF NOT EXISTS runs (
    id INTEGER PRIMARY KEY, serial TEXT NOT NULL, part TEXT NOT NULL, station_id TEXT, line TEXT,
    operator TEXT, software_version TEXT, limit_hash TEXT, started TEXT, finished TEXT,
    verdict TEXT, cause TEXT, unit_info TEXT, calibration TEXT, persistence TEXT);
CREATE INDEX IF NOT EXISTS runs_serial ON runs(serial);
CREATE TABLE IF NOT EXISTS phases (
    run_id INTEGER REFERENCES runs(id), seq INTEGER, name TEXT, outcome TEXT, duration_s REAL,
    message TEXT, log TEXT);
CREATE TABLE IF NOT EXISTS attempts (
    run_id INTEGER REFERENCES runs(id), attempt INTEGER, samples INTEGER, coverage REAL,
    target REAL, accepted INTEGER, raw_csv TEXT, refused TEXT);
CREATE TABLE IF NOT EXISTS measurements (
    run_id INTEGER REFERENCES runs(id), name TEXT, kind TEXT, value REAL, unit TEXT, low REAL,
    high REAL, verdict TEXT, data TEXT);
CREATE TABLE IF NOT EXISTS params (
    run_id INTEGER REFERENCES runs(id), stage TEXT, name TEXT, value REAL);
CREATE TABLE IF NOT EXISTS attachments (
    run_id INTEGER REFERENCES runs(id), name TEXT, mime TEXT, content BLOB);
"""
# Columns added since the first schema: files written by older versions get them on open.
ADDED_COLUMNS = {
    "attempts": {"refused": "TEXT", "repeats": "INTEGER", "sensor_rate_hz": "REAL"},
    "runs": {"owner": "TEXT", "aborted_phase": "TEXT", "left_changed": "TEXT", "unverified_params": "TEXT",
             "earlier_runs": "INTEGER"},
}
RUNNING = "running"


def _owner() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


def _alive(owner: str | None) -> bool:
    """Is the process that wrote a ``running`` row still there?  Another PC's process cannot be
    checked and counts as alive; a row without a writer (older versions) as dead."""
    host, _, pid = (owner or "").rpartition(":")
    if not pid.isdigit():
        return False
    if host != socket.gethostname():
        return True
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


class SqliteSink:
    def __init__(self, path: Path) -> None:
        self.path = path
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            self.db = sqlite3.connect(path)
            self.db.executescript(SCHEMA)
            for table, columns in ADDED_COLUMNS.items():
                have = {row[1] for row in self.db.execute(f"PRAGMA table_info({table})")}
                for name, kind in columns.items():
                    if name not in have:
                        self.db.execute(f"ALTER TABLE {table} ADD COLUMN {name} {kind}")
            self.db.commit()
        except (OSError, sqlite3.Error) as exc:
            raise StationFault(f"results store {path}: {exc}") from exc
        self.mark_incomplete()

    def mark_incomplete(self) -> int:
        """Runs left ``running`` by a process that no longer exists (killed, power lost) become
        ``incomplete``: never counted as passed, their raw data kept."""
        stale = [(rid,) for rid, owner in self.db.execute("SELECT id, owner FROM runs WHERE verdict=?", (RUNNING,))
                 if not _alive(owner)]
        with self.db:
            self.db.executemany("UPDATE runs SET verdict='incomplete', cause='the station process ended before the "
                                "run finished' WHERE id=?", stale)
        return len(stale)

    def close(self) -> None:
        self.db.close()

    def location(self, record: RunRecord) -> str:
        return f"{self.path} run {record.run_id}"

    def begin(self, record: RunRecord) -> None:
        with self.db:
            cur = self.db.execute(
                "INSERT INTO runs (serial, part, station_id, line, operator, software_version, limit_hash,"
                " started, verdict, owner, earlier_runs) VALUES (?,?,?,?,?,?,?,?,?,?,?)",
                (record.serial, record.part, record.station_id, record.line, record.operator,
                 record.software_version, record.limit_hash, record.started, RUNNING, _owner(),
                 record.earlier_runs))
            record.run_id = cur.lastrowid

    def save_attempt(self, record: RunRecord, attempt: AttemptRecord) -> None:
        if record.run_id is None:
            self.begin(record)
        with self.db:
            self.db.execute("INSERT INTO attempts (run_id, attempt, samples, coverage, target, accepted,"
                            " raw_csv, refused, repeats, sensor_rate_hz) VALUES (?,?,?,?,?,?,?,?,?,?)",
                            (record.run_id, attempt.attempt, attempt.samples, attempt.coverage,
                             attempt.target, int(attempt.accepted), attempt.raw_csv, attempt.refused,
                             attempt.repeats, attempt.sensor_rate_hz))

    def finish(self, record: RunRecord) -> None:
        if record.run_id is None:
            self.begin(record)
        rid = record.run_id
        with self.db:
            self.db.execute(
                "UPDATE runs SET finished=?, verdict=?, cause=?, unit_info=?, calibration=?, persistence=?,"
                " aborted_phase=?, left_changed=?, unverified_params=? WHERE id=?",
                (record.finished, str(record.verdict), record.cause, json.dumps(record.unit_info),
                 json.dumps(record.calibration) if record.calibration else None,
                 json.dumps(record.persistence), record.aborted_phase,
                 json.dumps(record.left_changed) if record.left_changed else None,
                 json.dumps(record.unverified_params) if record.unverified_params else None, rid))
            # the fit may refuse an attempt after its raw data were saved: final verdicts per attempt
            self.db.executemany("UPDATE attempts SET accepted=?, refused=? WHERE run_id=? AND attempt=?",
                                [(int(a.accepted), a.refused, rid, a.attempt) for a in record.attempts])
            self.db.executemany("INSERT INTO phases VALUES (?,?,?,?,?,?,?)", [
                (rid, i, p.name, str(p.outcome), p.duration_s, p.message, "\n".join(p.log))
                for i, p in enumerate(record.phases)])
            self.db.executemany("INSERT INTO measurements VALUES (?,?,?,?,?,?,?,?,?)",
                                [_measurement_row(rid, m) for m in _flatten(record.measurements)])
            for stage, params in (("before", record.params_before), ("written", record.params_written),
                                  ("read_back", record.params_read_back)):
                self.db.executemany("INSERT INTO params VALUES (?,?,?,?)",
                                    [(rid, stage, k, float(v)) for k, v in params.items()])
            self.db.executemany("INSERT INTO attachments VALUES (?,?,?,?)",
                                [(rid, a.name, a.mime, a.content) for a in record.attachments])

    def history(self, serial: str) -> list[dict[str, Any]]:
        """Every run of a unit, oldest first, with attempts and failed measurements."""
        self.db.row_factory = sqlite3.Row
        try:
            runs = [dict(r) for r in self.db.execute(
                "SELECT id, serial, part, station_id, line, operator, started, finished, verdict, cause,"
                " limit_hash, calibration, aborted_phase FROM runs WHERE serial=? ORDER BY id", (serial,))]
            for run in runs:
                run["attempts"] = [dict(r) for r in self.db.execute(
                    "SELECT attempt, samples, coverage, accepted, refused FROM attempts"
                    " WHERE run_id=? ORDER BY attempt",
                    (run["id"],))]
                run["failed"] = [dict(r) for r in self.db.execute(
                    "SELECT name, value, unit, low, high FROM measurements WHERE run_id=? AND verdict='fail'",
                    (run["id"],))]
                run["calibration"] = json.loads(run["calibration"]) if run["calibration"] else None
        finally:
            self.db.row_factory = None
        return runs


def _flatten(measurements):
    for m in measurements:
        yield m
        if isinstance(m, Array):
            yield from m.aggregations


def _measurement_row(rid: int, m) -> tuple:
    if isinstance(m, Numeric):
        return (rid, m.name, "numeric", m.value, m.unit, m.low, m.high, str(m.verdict), None)
    if isinstance(m, Array):
        return (rid, m.name, "array", None, m.unit, None, None, None, json.dumps(m.values))
    if isinstance(m, Json):
        return (rid, m.name, "json", None, None, None, None, None, json.dumps(m.data))
    return (rid, getattr(m, "name", "?"), "other", None, None, None, None, None, json.dumps(asdict(m)))


def results_path(station: Any, station_dir: Path) -> Path:
    """The store's file: a relative path is relative to the station file's directory."""
    return Path(station_dir) / Path(station.results.path).expanduser()


def _factory(station: Any, station_dir: Path) -> SqliteSink:
    return SqliteSink(results_path(station, station_dir))


@hookimpl
def magline_register_result_sinks(register):
    register("sqlite", _factory)
