"""Bring a results store to the schema this magline writes, or refuse it with a clear message.

* a new, empty database gets every migration;
* a SQLite file written by magline before migrations existed (no ``alembic_version``) is upgraded
  in place: the columns the old sink added over time are added where missing, it is stamped as the
  baseline, then migrated — every run kept;
* a store at a revision this magline does not know (written by a newer version) is refused: an
  older program must not write into a schema it does not understand.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from sqlalchemy import inspect, text
from sqlalchemy.exc import SQLAlchemyError

from magline.core.faults import StationFault

if TYPE_CHECKING:
    from alembic.config import Config
    from sqlalchemy import Connection, Engine

MIGRATIONS = Path(__file__).parent / "migrations"
BASELINE = "0001"
# The newest migration's revision.  Why a constant beside what alembic computes: a store already at it
# (every store, every day but the one magline is upgraded) is recognised by one query, without
# importing alembic and every migration script — a tenth of a second at each store opened, twice for a
# station that forwards to a server.  tests/test_results_store.py holds it to alembic's own head.
HEAD = "0018"
# Columns the pre-migration SQLite sink added to files written by still older versions.
PRE_BASELINE_COLUMNS = {
    "attempts": {"refused": "TEXT", "repeats": "INTEGER", "sensor_rate_hz": "REAL"},
    "runs": {"owner": "TEXT", "aborted_phase": "TEXT", "left_changed": "TEXT", "unverified_params": "TEXT",
             "earlier_runs": "INTEGER"},
}


# What the pre-migration sink created (CREATE IF NOT EXISTS): a legacy file lacking a table gets it.
PRE_BASELINE_TABLES = (
    "CREATE TABLE IF NOT EXISTS runs (id INTEGER PRIMARY KEY, serial TEXT NOT NULL, part TEXT NOT NULL, "
    "station_id TEXT, line TEXT, operator TEXT, software_version TEXT, limit_hash TEXT, started TEXT, finished TEXT, "
    "verdict TEXT, cause TEXT, unit_info TEXT, calibration TEXT, persistence TEXT)",
    "CREATE INDEX IF NOT EXISTS runs_serial ON runs(serial)",
    "CREATE TABLE IF NOT EXISTS phases (run_id INTEGER REFERENCES runs(id), seq INTEGER, name TEXT, outcome TEXT, "
    "duration_s REAL, message TEXT, log TEXT)",
    "CREATE TABLE IF NOT EXISTS attempts (run_id INTEGER REFERENCES runs(id), attempt INTEGER, samples INTEGER, "
    "coverage REAL, target REAL, accepted INTEGER, raw_csv TEXT)",
    "CREATE TABLE IF NOT EXISTS measurements (run_id INTEGER REFERENCES runs(id), name TEXT, kind TEXT, value REAL, "
    "unit TEXT, low REAL, high REAL, verdict TEXT, data TEXT)",
    "CREATE TABLE IF NOT EXISTS params (run_id INTEGER REFERENCES runs(id), stage TEXT, name TEXT, value REAL)",
    "CREATE TABLE IF NOT EXISTS attachments (run_id INTEGER REFERENCES runs(id), name TEXT, mime TEXT, content BLOB)",
)
LEGACY_TABLES = {"runs", "phases", "attempts", "measurements", "params", "attachments"}


class StoreTooNew(StationFault):
    """The store was written by a newer magline."""


def _config(connection: Connection) -> Config:
    from alembic.config import Config

    cfg = Config()
    cfg.set_main_option("script_location", str(MIGRATIONS))
    cfg.attributes["connection"] = connection
    return cfg


def head_revision() -> str:
    from alembic.script import ScriptDirectory

    return ScriptDirectory(str(MIGRATIONS)).get_current_head()


def current_revision(connection: Connection) -> str | None:
    from alembic.runtime.migration import MigrationContext

    return MigrationContext.configure(connection).get_current_revision()


def recorded_revision(conn: Connection) -> str | None:
    """The revision the store says it is at, in one query without alembic (None: none recorded).  Raises
    the driver's error on a store without ``alembic_version`` (a new or a legacy one)."""
    found = [row[0] for row in conn.execute(text("SELECT version_num FROM alembic_version"))]
    return found[0] if len(found) == 1 else None


def _at_head(engine: Engine) -> bool:
    """The store's recorded revision is :data:`HEAD` (one query; a store without the table is not)."""
    try:
        with engine.connect() as conn:
            return recorded_revision(conn) == HEAD
    except SQLAlchemyError:
        return False  # no alembic_version yet: a new or a legacy store, for the full path below


def upgrade(engine: Engine, where: str) -> str:
    """Migrate the store to the head revision; return it."""
    if _at_head(engine):
        return HEAD
    from alembic import command
    from alembic.script import ScriptDirectory
    from alembic.util import CommandError

    with engine.begin() as conn:
        tables = set(inspect(conn).get_table_names())
        if tables & LEGACY_TABLES and "alembic_version" not in tables:
            _adopt_legacy(conn)
            command.stamp(_config(conn), BASELINE)
        current = current_revision(conn)
        script = ScriptDirectory(str(MIGRATIONS))
        if current is not None:
            try:
                script.get_revision(current)
            except CommandError:
                raise StoreTooNew(f"results store {where} is at schema revision {current}, newer than this magline "
                                  f"knows (up to {script.get_current_head()}): upgrade magline") from None
        command.upgrade(_config(conn), "head")
    return head_revision()


def _adopt_legacy(conn: Connection) -> None:
    """A file from the hand-written sink: the tables and columns it may lack, before it is stamped as
    the baseline."""
    for statement in PRE_BASELINE_TABLES:
        conn.execute(text(statement))
    inspector = inspect(conn)
    for table, columns in PRE_BASELINE_COLUMNS.items():
        have = {c["name"] for c in inspector.get_columns(table)}
        for name, kind in columns.items():
            if name not in have:
                conn.execute(text(f"ALTER TABLE {table} ADD COLUMN {name} {kind}"))
