"""The built-in ``sqlite`` results sink (``results: {sink: sqlite, path: …}``): one file beside the
station file, written by :mod:`.sqlite_store`.

Why a module of its own: every command loads every plugin, and this registration must cost nothing
until a station opens its store (SQLAlchemy's import is a fifth of a second).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from magline.core.plugins import hookimpl


def _factory(station: Any, station_dir: Path, entry: Any, options: Any) -> Any:
    from magline.core.results.sqlite_store import SqliteSink, results_path

    return SqliteSink(results_path(station, station_dir, entry))


@hookimpl
def magline_register_result_sinks(register):
    # its settings are the entry's own keys (path, reports), never under options
    register("sqlite", _factory, options="magline.core.station.no_options:NoOptions")
