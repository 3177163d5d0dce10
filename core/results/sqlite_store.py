"""The embedded results store: one SQLite file named in the station file (``results.sink: sqlite``).

Why SQLite: a real database with transactions on a line PC, no server, readable by any quality
tool.  WAL mode and a busy timeout let several station processes on one PC write to one file.
A relative path is relative to the station file's directory (the embedded demo's: the directory
magline runs in).  The schema is the shared one (:mod:`.tables`), migrated on open.
"""

from __future__ import annotations

import sqlite3
from pathlib import Path
from typing import Any

from sqlalchemy import create_engine, event

from magline.core.faults import StationFault
from magline.core.results.new_sqlite import create_at_head
from magline.core.results.store import SqlStore

BUSY_TIMEOUT_MS = 10_000


def sqlite_engine(path: Path) -> Any:
    engine = create_engine(f"sqlite:///{path}")

    @event.listens_for(engine, "connect")
    def _pragmas(dbapi_connection: Any, _: Any) -> None:
        cur = dbapi_connection.cursor()
        cur.execute("PRAGMA journal_mode=WAL")
        cur.execute(f"PRAGMA busy_timeout={BUSY_TIMEOUT_MS}")
        cur.close()

    return engine


class StoreDamaged(StationFault):
    """The store's file fails SQLite's integrity check: nothing is read from it or written to it."""


def integrity_problem(path: Path) -> str | None:
    """SQLite's ``quick_check`` of an existing file (pages, records, indexes; no full cross-check):
    None when it is sound, else its first complaint."""
    if not path.exists() or path.stat().st_size == 0:
        return None
    try:
        conn = sqlite3.connect(f"file:{path}?mode=ro", uri=True, timeout=BUSY_TIMEOUT_MS / 1000)
    except sqlite3.Error as exc:
        return str(exc)
    try:
        rows = conn.execute("PRAGMA quick_check(3)").fetchall()
    except sqlite3.DatabaseError as exc:
        return str(exc)
    finally:
        conn.close()
    complaints = [r[0] for r in rows if r[0] != "ok"]
    return "; ".join(complaints) or None


class SqliteSink(SqlStore):
    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise StationFault(f"results store {path}: {exc.strerror}") from exc
        problem = integrity_problem(self.path)
        if problem is not None:  # refused before a unit is touched and before anything is written
            raise StoreDamaged(
                f"results store {self.path} is damaged ({problem}): nothing was read or written — restore the "
                "file from a backup (or run sqlite3's .recover into a new file), or point results.path at a new "
                "file; a sql station's queued records are safe in its outbox (magline sync)")
        try:
            create_at_head(self.path)
        except (OSError, sqlite3.Error) as exc:
            raise StationFault(f"results store {path}: {exc}") from exc
        super().__init__(sqlite_engine(self.path), str(self.path))


def results_path(station: Any, station_dir: Path, entry: Any = None) -> Path:
    """The store's file: a relative path is relative to the station file's directory."""
    return Path(station_dir) / Path((entry or station.main_results).path).expanduser()

