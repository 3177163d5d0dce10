"""The results store as the dashboard opens it: read-only, whatever the credentials allow.

Why read-only at the connection and not only by the code: the dashboard is served to a factory network,
and the store it reads is the line's quality record.  SQLite is opened with ``mode=ro`` (the file cannot be
written through this connection, nor created when missing); PostgreSQL sessions are
``default_transaction_read_only`` — and a line gives the dashboard a role that can only read
(:data:`READ_ONLY_ROLE`).
"""

from __future__ import annotations

import sqlite3
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sqlalchemy import create_engine, event, inspect, select
from sqlalchemy.engine import make_url
from sqlalchemy.exc import ArgumentError, SQLAlchemyError
from sqlalchemy.pool import QueuePool

from magline.core.faults import StationFault
from magline.core.results import schema_version
from magline.core.results.store import reason
from magline.core.results.tables import runs

READ_ONLY_ROLE = """\
CREATE ROLE magline_dashboard LOGIN PASSWORD '…';
GRANT CONNECT ON DATABASE magline TO magline_dashboard;
GRANT USAGE ON SCHEMA public TO magline_dashboard;
GRANT SELECT ON ALL TABLES IN SCHEMA public TO magline_dashboard;
ALTER DEFAULT PRIVILEGES IN SCHEMA public GRANT SELECT ON TABLES TO magline_dashboard;"""


@dataclass
class ReadOnlyStore:
    """An engine that cannot write, and how the store is named to people (a file, a server without its
    password)."""

    engine: Any
    where: str
    kind: str  # "sqlite" or the server's dialect
    url: str | None = None  # a server's connection string, for its notifications (psycopg's form)

    def close(self) -> None:
        self.engine.dispose()


def open_read_only(target: str) -> ReadOnlyStore:
    """``target``: a SQLite file's path, or a SQLAlchemy URL (``postgresql+psycopg://role:pw@host/db``).
    A store that cannot be opened, or holds no magline runs, is one :class:`StationFault` line."""
    if "://" not in target:
        return _sqlite(Path(target))
    try:
        url = make_url(target)
    except ArgumentError:
        raise StationFault(f"results store {target!r} is neither a file nor a database URL") from None
    if url.get_backend_name() == "sqlite":
        return _sqlite(Path(url.database or ""))
    where = url.render_as_string(hide_password=True)
    engine = create_engine(url, pool_pre_ping=True)

    @event.listens_for(engine, "connect")
    def _read_only(dbapi_connection: Any, _: Any) -> None:
        cursor = dbapi_connection.cursor()
        cursor.execute("SET default_transaction_read_only = on")
        cursor.close()
        dbapi_connection.commit()

    plain = url.set(drivername=url.get_backend_name()).render_as_string(hide_password=False)
    return _checked(ReadOnlyStore(engine, where, url.get_backend_name(), plain))


def _sqlite(path: Path) -> ReadOnlyStore:
    if not path.is_file():
        raise StationFault(f"results store {path}: no such file (a station writes it when it records its first unit)")
    resolved = path.resolve()

    def connect() -> sqlite3.Connection:
        return sqlite3.connect(f"file:{resolved}?mode=ro", uri=True, check_same_thread=False, timeout=10.0)

    # a pool of real connections shared by the server's threads: an in-memory URL's default (one connection
    # per thread, closed behind another's back) crashed the process under a dozen open pages
    engine = create_engine("sqlite://", creator=connect, poolclass=QueuePool, pool_size=5, max_overflow=20)
    return _checked(ReadOnlyStore(engine, str(path), "sqlite"))


def _checked(store: ReadOnlyStore) -> ReadOnlyStore:
    """The store answers and holds magline's tables."""
    try:
        with store.engine.connect() as conn:
            if not inspect(conn).has_table("runs"):
                raise StationFault(f"results store {store.where}: no magline runs table (is it a magline store?)")
            conn.execute(select(runs.c.id).limit(1)).all()
            found = schema_version.recorded_revision(conn) if inspect(conn).has_table("alembic_version") else None
            if found != schema_version.HEAD:
                # read-only, the dashboard cannot bring the store up to date: a station (or ``magline sync``) does
                raise StationFault(f"results store {store.where}: schema {found or 'before migrations'}, this "
                                   f"magline reads {schema_version.HEAD} — a station of this version brings it up "
                                   "to date when it records its next unit (or run `magline sync` on one)")
    except SQLAlchemyError as exc:
        store.close()
        raise StationFault(f"results store {store.where}: {reason(exc)}") from None
    return store
