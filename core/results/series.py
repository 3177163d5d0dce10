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
from sqlalchemy import Connection, Float, Integer, func, select
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
    refusals: list[list[str]] = field(default_factory=list)  # per run: why attempts were not used (with_attempts)
    failed: list[list[str]] = field(default_factory=list)  # per run: measurements that failed (with_attempts)
    source: str = ""  # which store the runs came from (people's words)

    def __len__(self) -> int:
        return len(self.runs)


def load_series(conn: Connection, where: RunFilter, last: int | None = None, names: Sequence[str] | None = None,
                with_attempts: bool = False) -> RunSeries:
    """The latest ``last`` runs matching ``where`` (all when None), oldest first, with their numeric
    measurements (only ``names`` when given)."""
    chosen = where.apply(select(runs.c.id)).order_by(runs.c.id.desc())
    if last is not None:
        chosen = chosen.limit(last)
    chosen = chosen.subquery("chosen")
    found = [dict(r._mapping) for r in conn.execute(
        select(*(runs.c[f] for f in RUN_FIELDS)).join(chosen, chosen.c.id == runs.c.id).order_by(runs.c.id))]
    series = RunSeries(runs=found)
    if not found:
        return series
    position = {r["id"]: i for i, r in enumerate(found)}  # a run added meanwhile is not in it: skipped below

    def of(table: Any) -> Any:  # the chosen runs joined to a child table: index lookups, never a scan
        return chosen.join(table, table.c.run_id == chosen.c.id)

    match = measurements.c.kind == "numeric"
    if names:
        match = match & measurements.c.name.in_(list(names))
    for name, run_ids, values in _grouped(conn, of(measurements), match):
        keep = [(position[r], v) for r, v in zip(run_ids, values, strict=True) if r in position]
        column = np.full(len(found), np.nan)
        if keep:
            at, vals = zip(*keep, strict=True)
            column[list(at)] = np.asarray(vals, dtype=np.float64)
        series.values[name] = column
        series.limits[name] = Limit(None, None, None)
    recent = found[max(0, len(found) - 50)]["id"]  # the last 50 runs are enough to find every current limit
    for row in conn.execute(select(measurements.c.name, measurements.c.low, measurements.c.high, measurements.c.unit)
                            .select_from(of(measurements)).where(match & (chosen.c.id >= recent))
                            .order_by(measurements.c.run_id)):
        series.limits[row.name] = Limit(row.low, row.high, row.unit)
    if with_attempts:
        counts = np.zeros(len(found), dtype=int)
        series.refusals = [[] for _ in found]
        for rid, refused in conn.execute(select(attempts.c.run_id, attempts.c.refused).select_from(of(attempts))):
            if rid in position:
                counts[position[rid]] += 1
                if refused:
                    series.refusals[position[rid]].append(refused)
        series.attempts = counts
        series.failed = [[] for _ in found]
        for rid, name in conn.execute(select(measurements.c.run_id, measurements.c.name).select_from(
                of(measurements)).where(measurements.c.verdict == "fail")):
            if rid in position:
                series.failed[position[rid]].append(name)
    return series


def _grouped(conn: Connection, source: Any, match: Any) -> list[tuple[str, Sequence[int], Sequence[float]]]:
    if conn.dialect.name == "postgresql":
        query = (select(measurements.c.name,
                        func.array_agg(measurements.c.run_id, type_=ARRAY(Integer)),
                        func.array_agg(measurements.c.value, type_=ARRAY(Float)))
                 .select_from(source).where(match).group_by(measurements.c.name))
        return [(name, rids, [np.nan if v is None else v for v in values])
                for name, rids, values in conn.execute(query)]
    rows = conn.execute(select(measurements.c.name, measurements.c.run_id, measurements.c.value)
                        .select_from(source).where(match).order_by(measurements.c.name)).all()
    out: dict[str, tuple[list[int], list[float]]] = {}
    for name, rid, value in rows:
        rids, values = out.setdefault(name, ([], []))
        rids.append(rid)
        values.append(np.nan if value is None else value)
    return [(name, rids, values) for name, (rids, values) in out.items()]
