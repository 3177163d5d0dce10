"""``magline dashboard``: open the store read-only, serve the pages."""

from __future__ import annotations

import secrets
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from magline.core.dashboard.app import create_app
from magline.core.dashboard.store import READ_ONLY_ROLE, ReadOnlyStore, open_read_only
from magline.core.faults import StationFault
from magline.core.operator_ui.screen.serve import is_loopback, listening_socket

if TYPE_CHECKING:
    from magline.core.quality.trends import Shifts
    from magline.core.station import Station

ROLE_HINT = ("the dashboard only reads: on PostgreSQL give it a role that can only read —\n"
             + "\n".join(f"  {line}" for line in READ_ONLY_ROLE.splitlines()))


def station_store(station: Station, where: Path) -> str:
    """The store a station file names first: its SQLite file, or its server's URL (``results.url_env``)."""
    entry = station.main_results
    if entry.sink == "sqlite":
        from magline.core.results.sqlite_store import results_path

        return str(results_path(station, where))
    if entry.sink == "sql":
        from magline.core.results.sql_store import server_url

        return server_url(entry.url_env).render_as_string(hide_password=False)
    raise StationFault(f"the station's results sink {entry.sink!r} is not a SQL store: give --store URL")


def serve(target: str, shifts: Shifts, host: str, port: int) -> int:
    import uvicorn

    try:
        store: ReadOnlyStore = open_read_only(target)
    except StationFault as exc:
        print(f"magline dashboard: {exc}", file=sys.stderr)
        return 2
    try:
        sock = listening_socket(host, port)
    except OSError as exc:
        store.close()
        print(f"magline dashboard: cannot listen on {host}:{port}: {exc.strerror or exc} — give another --port",
              file=sys.stderr)
        return 2
    port = sock.getsockname()[1]  # the port it is on (--port 0: the one the system chose)
    token = None if is_loopback(host) else secrets.token_urlsafe(18)
    address = f"http://{host}:{port}/"
    print(f"dashboard of {store.where} on " + (f"{address}?token={token} (token shown once)" if token else address),
          flush=True)
    if store.kind != "sqlite":
        print(ROLE_HINT, flush=True)
    app = create_app(store, shifts, token)
    try:
        uvicorn.Server(uvicorn.Config(app, host=host, port=port, log_level="warning")).run(sockets=[sock])
    finally:
        app.state.wakeups.close()
        store.close()
        sock.close()
    return 0
