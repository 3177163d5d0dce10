"""First-pass yield and failure causes over time, and split by who and what made the units.

Why a module of its own: the batch page draws these trends and ``spc --json`` carries the same numbers,
so that every bar and point on the page can be recomputed from the data (issue 45).  A drop in yield
that shows on one station, one operator's shifts or one product, or failures that gather on one
compass (the GPS mast's, not the board's), is the lead a quality engineer follows first.

Periods are local days of the computer magline runs on — what a plant calls "Tuesday" — or, given
the line's shift starts (``06:00,14:00,22:00``), shifts: a shift that runs past midnight belongs to
the day it started on.  The yield counts first runs of a serial that were judged (PASS or FAIL): a
station fault is not the unit's, and a re-test does not improve the first pass (as in
:mod:`magline.core.quality.yields`).
"""

from __future__ import annotations

import argparse
from collections import Counter
from dataclasses import dataclass, field
from datetime import datetime, time, timedelta
from typing import TYPE_CHECKING, Any

from magline.core.measurements import base_name

if TYPE_CHECKING:
    from magline.core.results.series import RunSeries

GROUPINGS = {"station_id": "station", "operator": "operator", "part": "product"}  # run field → people's word


@dataclass(frozen=True)
class Shifts:
    """The line's shift starts (local clock times), earliest first; none: periods are days."""

    starts: tuple[time, ...] = ()

    @classmethod
    def parse(cls, text: str | None) -> Shifts:
        """From ``06:00,14:00,22:00``; ValueError naming the bad entry."""
        if not text:
            return cls()
        starts = []
        for item in text.split(","):
            try:
                starts.append(time.fromisoformat(item.strip()))
            except ValueError:
                raise ValueError(f"{item.strip()!r} is not a clock time (give e.g. 06:00,14:00,22:00)") \
                    from None
        if len(set(starts)) != len(starts):
            raise ValueError("a shift start is given twice")
        return cls(tuple(sorted(starts)))

    def start_of(self, now: datetime) -> datetime:
        """When the shift running at ``now`` began (local time; aware): the latest start at or before
        ``now`` — yesterday's last when ``now`` is before today's first; with no starts, local midnight."""
        local = now.astimezone()
        midnight = local.replace(hour=0, minute=0, second=0, microsecond=0)
        if not self.starts:
            return midnight
        clock = local.time().replace(tzinfo=None)
        before = [start for start in self.starts if start <= clock]
        day = midnight if before else midnight - timedelta(days=1)
        start = before[-1] if before else self.starts[-1]
        return day.replace(hour=start.hour, minute=start.minute, second=start.second)

    def period(self, started: Any) -> str:
        """The period a run that started at ``started`` (stored UTC text or a datetime) belongs to:
        ``2026-11-27`` or ``2026-11-27 shift 2 (14:00)``."""
        when = (started if isinstance(started, datetime) else datetime.fromisoformat(str(started))).astimezone()
        if not self.starts:
            return when.date().isoformat()
        clock = when.time().replace(tzinfo=None)
        before = [k for k, start in enumerate(self.starts) if start <= clock]
        if before:
            k, day = before[-1], when.date()
        else:  # before the first start: the last shift of the day before, still running
            k, day = len(self.starts) - 1, (when - timedelta(days=1)).date()
        return f"{day.isoformat()} shift {k + 1} ({self.starts[k].strftime('%H:%M')})"


def shifts_argument(text: str) -> Shifts:
    """argparse ``type=`` for ``--shifts``: a bad clock time is a usage error (exit 2)."""
    try:
        return Shifts.parse(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


@dataclass
class YieldPoint:
    period: str
    first_runs: int = 0  # judged first runs of a serial in the period
    first_pass: int = 0

    @property
    def fpy(self) -> float | None:
        return self.first_pass / self.first_runs if self.first_runs else None


@dataclass
class Trends:
    """Per grouping (``all``, ``station``, ``operator``, ``product``): per group its yield per period;
    failure causes per period, per grouping's group and per compass."""

    periods: list[str]
    fpy: dict[str, dict[str, list[YieldPoint]]] = field(default_factory=dict)
    causes_by_period: dict[str, Counter] = field(default_factory=dict)
    causes_by: dict[str, dict[str, Counter]] = field(default_factory=dict)  # grouping → group → cause → units
    causes: list[str] = field(default_factory=list)  # every cause, most frequent first

    def to_json(self) -> dict:
        return {"periods": self.periods,
                "first_pass_yield": {grouping: {group: [{"period": p.period, "first_runs": p.first_runs,
                                                         "first_pass": p.first_pass, "fpy": p.fpy} for p in points]
                                                for group, points in groups.items()}
                                     for grouping, groups in self.fpy.items()},
                "failure_causes": {"order": self.causes,
                                   "by_period": {p: dict(c) for p, c in self.causes_by_period.items()},
                                   **{f"by_{grouping}": {g: dict(c) for g, c in groups.items()}
                                      for grouping, groups in self.causes_by.items()}}}


def compass_of(name: str) -> str:
    """Which compass (or pair) a measurement is of: its prefix, the primary's ``mag1`` without one."""
    prefix = name[: len(name) - len(base_name(name))].rstrip(".")
    return prefix or "mag1"


def trends(series: RunSeries, shifts: Shifts | None = None) -> Trends:
    """The yield and failure trends of ``series`` (runs oldest first; ``failed`` loaded with them)."""
    shifts = shifts or Shifts()
    period_of = [shifts.period(run["started"]) for run in series.runs]
    periods = sorted(set(period_of))
    out = Trends(periods=periods)
    first = [i for i, run in enumerate(series.runs)
             if run["verdict"] in ("pass", "fail") and not run.get("earlier_runs")]
    for grouping, word in (("all", "all"), *GROUPINGS.items()):
        groups: dict[str, dict[str, YieldPoint]] = {}
        for i in first:
            run = series.runs[i]
            group = "all units" if grouping == "all" else str(run.get(grouping) or "—")
            point = groups.setdefault(group, {}).setdefault(period_of[i], YieldPoint(period_of[i]))
            point.first_runs += 1
            point.first_pass += run["verdict"] == "pass"
        out.fpy[word] = {g: [points[p] for p in periods if p in points] for g, points in sorted(groups.items())}
    total: Counter = Counter()
    by: dict[str, dict[str, Counter]] = {word: {} for word in (*GROUPINGS.values(), "compass")}
    for i, failed in enumerate(series.failed):
        run = series.runs[i]
        if run["verdict"] != "fail":
            continue
        causes = sorted({base_name(name) for name in failed})
        total.update(causes)
        out.causes_by_period.setdefault(period_of[i], Counter()).update(causes)
        for grouping, word in GROUPINGS.items():
            by[word].setdefault(str(run.get(grouping) or "—"), Counter()).update(causes)
        for compass in sorted({compass_of(name) for name in failed}):
            by["compass"].setdefault(compass, Counter()).update(
                {base_name(name) for name in failed if compass_of(name) == compass})
    out.causes = [cause for cause, _ in total.most_common()]
    out.causes_by = {word: dict(sorted(groups.items())) for word, groups in by.items()}
    return out
