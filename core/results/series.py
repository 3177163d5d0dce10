"""What process statistics read: the latest runs matching a filter, and each numeric measurement
as one array aligned with them.

Why arrays and a server-side aggregate: the statistics of a part's last 10,000 units read about
200,000 measurement rows.  Fetched one row at a time into Python that costs seconds on a server;
PostgreSQL groups them itself (``array_agg`` per measurement name, ~20 rows back), SQLite, which
runs in this process, returns plain rows that NumPy groups.  Either way the caller gets
``values[name][i]`` for ``runs[i]`` (NaN where a run lacks the measurement: an ERROR before fit).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from sqlalchemy import Connection, Float, Integer, any_, cast, func, select
from sqlalchemy.dialects.postgresql import ARRAY

from magline.core.results.reading import RunFilter
from magline.core.results.tables import attempts, measurements, runs

RUN_FIELDS = ("id", "run_uuid", "serial", "part", "station_id", "line", "operator", "started", "verdict", "cause",
              "earlier_runs", "limit_hash")


@dataclass
class Limit:
    low: float | None
    high: float | None
    unit: str | None


@dataclass
class RunSeries:
    runs: list[dict[str, Any]]  # oldest first
    values: dict[str, np.ndarray] = field(default_factory=dict)  # name -> values aligned with runs
    limits: dict[str, Limit] = field(default_factory=dict)  # as the newest run that had the measurement judged it
    attempts: np.ndarray | None = None  # acquisition attempts per run (retry rate), when asked for
    source: str = ""  # which store the runs came from (people's words)

    def __len__(self) -> int:
        return len(self.runs)


def load_series(conn: Connection, where: RunFilter, last: int | None = None, names: Sequence[str] | None = None,
                with_attempts: bool = False) -> RunSeries:
    """The latest ``last`` runs matching ``where`` (all when None), oldest first, with their numeric
    measurements (only ``names`` when given)."""
    query = where.apply(select(*(runs.c[f] for f in RUN_FIELDS))).order_by(runs.c.id.desc())
    if last is not None:
        query = query.limit(last)
    found = [dict(r._mapping) for r in conn.execute(query)][::-1]
    series = RunSeries(runs=found)
    if not found:
        return series
    ids = np.array([r["id"] for r in found], dtype=np.int64)
    position = {int(rid): i for i, rid in enumerate(ids)}
    match = _in_runs(conn, measurements.c.run_id, ids) & (measurements.c.kind == "numeric")
    if names:
        match = match & measurements.c.name.in_(list(names))
    for name, run_ids, values in _grouped(conn, match):
        column = np.full(len(found), np.nan)
        column[[position[int(r)] for r in run_ids]] = np.asarray(values, dtype=np.float64)
        series.values[name] = column
    for name in series.values:
        series.limits[name] = Limit(None, None, None)
    newest = conn.execute(select(measurements.c.name, measurements.c.low, measurements.c.high, measurements.c.unit,
                                 measurements.c.run_id)
                          .where(match & (measurements.c.run_id >= int(ids[max(0, len(ids) - 50)])))
                          .order_by(measurements.c.run_id))
    for row in newest:  # the last 50 runs are enough to find every measurement's current limits
        series.limits[row.name] = Limit(row.low, row.high, row.unit)
    if with_attempts:
        counts = dict(conn.execute(select(attempts.c.run_id, func.count()).where(
            _in_runs(conn, attempts.c.run_id, ids)).group_by(attempts.c.run_id)).all())
        series.attempts = np.array([counts.get(int(rid), 0) for rid in ids])
    return series


def _in_runs(conn: Connection, column: Any, ids: np.ndarray) -> Any:
    if conn.dialect.name == "postgresql":  # one array parameter: the index on run_id, no 10,000-term IN
        return column == any_(cast([int(i) for i in ids], ARRAY(Integer)))
    return column.in_([int(i) for i in ids])


def _grouped(conn: Connection, match: Any) -> list[tuple[str, Sequence[int], Sequence[float]]]:
    if conn.dialect.name == "postgresql":
        query = (select(measurements.c.name,
                        func.array_agg(measurements.c.run_id, type_=ARRAY(Integer)),
                        func.array_agg(measurements.c.value, type_=ARRAY(Float)))
                 .where(match).group_by(measurements.c.name))
        return [(name, rids, [np.nan if v is None else v for v in values])
                for name, rids, values in conn.execute(query)]
    rows = conn.execute(select(measurements.c.name, measurements.c.run_id, measurements.c.value)
                        .where(match).order_by(measurements.c.name)).all()
    out: dict[str, tuple[list[int], list[float]]] = {}
    for name, rid, value in rows:
        rids, values = out.setdefault(name, ([], []))
        rids.append(rid)
        values.append(np.nan if value is None else value)
    return [(name, rids, values) for name, (rids, values) in out.items()]

