"""A results store on a database server (``results: {sink: sql, url_env: MAGLINE_DB_URL}``), reached
through a local outbox (store-and-forward, :mod:`.forwarding`).

Why an environment variable: the station file names the variable, the line PC's environment holds
the SQLAlchemy URL (``postgresql+psycopg://user:password@host/db``), so no secret is ever in a
station file; the store is named to people with the password hidden.  The schema is the shared one
(:mod:`.tables`), migrated on open, so several stations and lines write to one database.
"""

from __future__ import annotations

import os
from typing import Any

from sqlalchemy import create_engine
from sqlalchemy.engine import make_url
from sqlalchemy.exc import ArgumentError

from magline.core.faults import StationFault
from magline.core.results.store import SqlStore


def server_url(url_env: str | None) -> Any:
    if not url_env:
        raise StationFault("results.sink 'sql' needs results.url_env: the name of the environment variable "
                           "that holds the database URL")
    url = os.environ.get(url_env)
    if not url:
        raise StationFault(f"the environment variable {url_env} (results.url_env) is not set: it must hold the "
                           "results database's URL, e.g. postgresql+psycopg://user:password@host/db")
    try:
        return make_url(url)
    except ArgumentError:
        raise StationFault(f"the environment variable {url_env} does not hold a database URL") from None


def server_store(url_env: str | None) -> SqlStore:
    """The server's store itself (no outbox): what reading commands and the forwarder talk to."""
    parsed = server_url(url_env)
    return SqlStore(create_engine(parsed, pool_pre_ping=True), parsed.render_as_string(hide_password=True))

