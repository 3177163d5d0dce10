"""The built-in ``sql`` results sink (``results: {sink: sql, url_env: MAGLINE_DB_URL}``): a database
server reached through a local outbox, written by :mod:`.sql_store` and :mod:`.forwarding`.

Why a module of its own: every command loads every plugin, and this registration must cost nothing
until a station opens its store (SQLAlchemy's import is a fifth of a second).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from magline.core.plugins import hookimpl


def _factory(station: Any, station_dir: Path, entry: Any, options: Any) -> Any:
    from magline.core.results.forwarding import ForwardingStore
    from magline.core.results.sql_store import server_url

    outbox = Path(station_dir) / Path(entry.outbox).expanduser()
    return ForwardingStore(outbox, server_url(entry.url_env))


@hookimpl
def magline_register_result_sinks(register):
    # its settings are the entry's own keys (url_env, outbox, reports), never under options
    register("sql", _factory, options="magline.core.station.no_options:NoOptions")
