"""``magline report RUN_ID|SERIAL``: a unit's report from the results store; and the station's own
report after each run (``results.reports: DIR``)."""

from __future__ import annotations

import re
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from magline.core.faults import StationFault
from magline.core.reports.unit_page import write_unit_page
from magline.core.results.contract import ReadsInSql
from magline.core.results.reading import RunNotFound, attempt_sensor_streams, find_run_or_serial, run_attempts

if TYPE_CHECKING:
    from sqlalchemy import Connection

    from magline.core.station import Station

UNSAFE = re.compile(r"[^A-Za-z0-9._-]+")


def stored_run(conn: Connection, wanted: str) -> dict[str, Any] | None:
    """A run by local id or UUID, else the latest run of a serial; with its attempts' raw arrays."""
    found = find_run_or_serial(conn, wanted)
    if found is not None:
        found["attempts"] = run_attempts(conn, found["id"], with_samples=True)
        for attempt in found["attempts"]:  # the other compasses' readings of the same tumble
            attempt["others"] = attempt_sensor_streams(conn, found["id"], attempt["attempt"])
    return found


def default_name(run: dict[str, Any]) -> str:
    return f"{UNSAFE.sub('_', run['serial'])}-run{run['id']}.html"


def write_report(engine: Any, wanted: str, output: Path | None, folder: Path = Path(), where: str = "") -> Path:
    """The run's report at ``output`` (else its default name in ``folder``); :class:`RunNotFound` names ``where``
    (the store) when there is no such run."""
    with engine.connect() as conn:
        run = stored_run(conn, wanted)
    if run is None:
        raise RunNotFound(wanted, where or "the results store")
    return write_unit_page(run, output or folder / default_name(run))


def write_missing_reports(engine: Any, runs: list[dict[str, Any]], folder: Path) -> list[Path]:
    """The unit report of every run in ``runs`` that has none in ``folder`` yet, under the name the
    station writes it under (a batch page's points open them), sharing one plotly.js in ``folder``."""
    from magline.core.reports.page import shared_plotly

    missing = [run for run in runs if not (folder / default_name(run)).is_file()]
    if not missing:
        return []
    src = shared_plotly(folder)
    written = []
    with engine.connect() as conn:
        for run in missing:
            stored = stored_run(conn, str(run["id"]))
            if stored is not None:
                written.append(write_unit_page(stored, folder / default_name(stored), src))
    return written


def report(store: Any, station: Station, wanted: str, output: str | None) -> int:
    if not isinstance(store, ReadsInSql):
        raise StationFault("this station's results sink is not a SQL store: reports read SQL stores only")
    try:
        path = write_report(store.engine, wanted, Path(output) if output else None, where=store.where)
    except RunNotFound as missing:  # as ``magline show`` says it
        print(missing, file=sys.stderr)
        return 1
    print(path)
    print(f"report of {wanted} from {store.where}", file=sys.stderr)
    return 0
