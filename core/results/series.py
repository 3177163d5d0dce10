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
from typing import TYPE_CHECKING, Any

import numpy as np
from sqlalchemy import case, func, literal, select, true

from magline.core.results.tables import attempts, measurements, runs

if TYPE_CHECKING:
    from sqlalchemy import Connection

    from magline.core.results.reading import RunFilter

RUN_FIELDS = ("id", "run_uuid", "serial", "part", "station_id", "line", "operator", "started", "verdict", "cause",
              "earlier_runs", "limit_hash", "reference_field_ut", "station_hash")


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
                with_attempts: bool = False, with_limits: bool = True, first: int | None = None) -> RunSeries:
    """The latest ``last`` runs matching ``where`` (all when None) — or, ``first``, the oldest that many
    (a Phase I baseline) — oldest first, with their numeric measurements (only ``names`` when given),
    the limits they were judged against (``with_limits``) and, ``with_attempts``, their acquisition
    attempts, refusals and failed measurements."""
    order = runs.c.id.asc() if first is not None else runs.c.id.desc()
    count = first if first is not None else last
    picked = where.apply(select(*(runs.c[f] for f in RUN_FIELDS))).order_by(order)
    found = [dict(r._mapping) for r in conn.execute(picked.limit(count) if count is not None else picked)]
    found = found if first is not None else found[::-1]
    series = RunSeries(runs=found)
    if not found:
        return series
    chosen = where.apply(select(runs.c.id)).order_by(order)
    chosen = (chosen.limit(count) if count is not None else chosen).subquery("chosen")
    position = {r["id"]: i for i, r in enumerate(found)}  # a run added meanwhile is not in it: skipped below

    match = measurements.c.kind == "numeric"
    if names:
        match = match & measurements.c.name.in_(list(names))
    ids = np.array([r["id"] for r in found], dtype=np.int64)  # ascending: runs are oldest first

    def place(run_ids: Sequence[int]) -> tuple[np.ndarray, np.ndarray]:
        """(positions in ``found``, which of ``run_ids`` are there) — vectorised, for 200,000 values."""
        rid = np.asarray(run_ids, dtype=np.int64)
        at = np.minimum(np.searchsorted(ids, rid), len(ids) - 1)
        return at, ids[at] == rid

    failed_at: list[tuple[str, np.ndarray]] = []
    values = _children(conn, chosen, measurements, ("name", "run_id", "value", "verdict"), match)
    for name, run_ids, column_values, failed_ids in _grouped(conn, values):
        at, known = place(run_ids)
        column = np.full(len(found), np.nan)
        column[at[known]] = np.asarray(column_values, dtype=np.float64)[known]
        series.values[name] = column
        series.limits[name] = Limit(None, None, None)
        if len(failed_ids):
            f_at, f_known = place(failed_ids)
            failed_at.append((name, f_at[f_known]))
    if with_limits:
        recent = found[max(0, len(found) - 50)]["id"]  # the last 50 runs are enough to find every current limit
        judged = _children(conn, chosen, measurements, ("name", "run_id", "low", "high", "unit"),
                           match & (measurements.c.run_id >= recent))
        for row in conn.execute(select(judged).order_by(judged.c.run_id)):
            series.limits[row.name] = Limit(row.low, row.high, row.unit)
    if with_attempts:
        counts = np.zeros(len(found), dtype=int)
        series.refusals = [[] for _ in found]
        for rid, refused in conn.execute(select(_children(conn, chosen, attempts, ("run_id", "refused"), true()))):
            if rid in position:
                counts[position[rid]] += 1
                if refused:
                    series.refusals[position[rid]].append(refused)
        series.attempts = counts
        series.failed = [[] for _ in found]
        for name, where_failed in failed_at:
            for i in where_failed.tolist():
                series.failed[i].append(name)
    return series


def _children(conn: Connection, chosen: Any, table: Any, columns: Sequence[str], where: Any) -> Any:
    """The rows of a child table (measurements, attempts) that belong to the chosen runs, as a
    subquery.  Found through the child's ``run_id`` index one run at a time: on PostgreSQL a
    LATERAL join says so (a plain join lets the planner pick a scan of every measurement ever
    stored — 17 million rows for a million units, seconds instead of tenths), and its ``OFFSET 0``
    keeps the planner from pulling the lateral subquery up into that plain join again; SQLite's
    planner makes the nested loop of itself."""
    cols = [table.c[c] for c in columns]
    if conn.dialect.name == "postgresql":
        per_run = (select(*cols).where((table.c.run_id == chosen.c.id) & where).offset(0)
                   .lateral(f"{table.name}_of_run"))
        return select(*per_run.c).select_from(chosen.join(per_run, true())).subquery()
    return select(*cols).select_from(chosen.join(table, table.c.run_id == chosen.c.id)).where(where).subquery()


def _grouped(conn: Connection, rows: Any) -> list[tuple[str, Sequence[int], Sequence[float], Sequence[int]]]:
    """(name, run ids, values, run ids where it failed) per measurement name, grouped by the
    database: about twenty rows come back, not 200,000.  PostgreSQL aggregates into arrays;
    SQLite into comma-separated text that NumPy parses: each REAL printed with ``%!.17g`` (the
    ``!`` flag makes SQLite print all 17 digits, so a measurement's value comes back bit for bit —
    0 of 150,000 differed; its own printf rounds a few doubles beyond 1e±200 in the last bit; its
    default text has 15), and a missing value as ``nan`` (``group_concat`` skips NULLs, which
    would misalign the lists)."""
    if conn.dialect.name == "postgresql":
        # as text too: 200,000 Python floats and ints built by the driver cost more than the query (PostgreSQL
        # ≥ 12 prints a float8 in its shortest exact form, so every value comes back bit for bit)
        def joined(column: Any, *where: Any) -> Any:
            aggregated = func.array_agg(column)
            return func.array_to_string(aggregated.filter(*where) if where else aggregated, ",", "nan")

        query = (select(rows.c.name, joined(rows.c.run_id), joined(rows.c.value),
                        joined(rows.c.run_id, rows.c.verdict == "fail"))
                 .group_by(rows.c.name))
        return [(name, np.fromstring(rids, dtype=np.int64, sep=","), np.fromstring(values, dtype=np.float64, sep=","),
                 np.fromstring(failed, dtype=np.int64, sep=",") if failed else [])
                for name, rids, values, failed in conn.execute(query)]
    query = (select(rows.c.name, func.group_concat(rows.c.run_id),
                    func.group_concat(case((rows.c.value.is_(None), literal("nan")),
                                           else_=func.printf("%!.17g", rows.c.value))),
                    func.group_concat(case((rows.c.verdict == "fail", rows.c.run_id))))
             .group_by(rows.c.name))
    return [(name, np.fromstring(rids, dtype=np.int64, sep=","), np.fromstring(values, dtype=np.float64, sep=","),
             np.fromstring(failed, dtype=np.int64, sep=",") if failed else [])
            for name, rids, values, failed in conn.execute(query)]
