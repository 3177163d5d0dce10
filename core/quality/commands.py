"""``magline spc``: read a part's latest units from the store, print the tables, write the page."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from magline.core.faults import StationFault
from magline.core.quality.spc import build, format_text, to_json
from magline.core.results.contract import KeepsSeries
from magline.core.results.reading import RunFilter
from magline.core.results.series import Limit
from magline.core.station import Station


def part_of(station: Station, part: str | None) -> str:
    """The part asked for, else the station's default, else its only product."""
    if part:
        return part
    if station.default_part:
        return station.default_part
    if len(station.products) == 1:
        return next(iter(station.products))
    raise StationFault(f"give --part: the station has several products ({', '.join(station.products)})")


def spc(store: Any, station: Station, args: argparse.Namespace) -> int:
    if not isinstance(store, KeepsSeries):
        raise StationFault("this station's results sink keeps no history: spc reads SQL stores only")
    part = part_of(station, args.part)
    where = RunFilter(part=part, station_id=args.station_id, since=args.since, until=args.until)
    series = store.series(where, last=args.last, names=args.measurement, with_attempts=True)
    if part in station.products:  # Cpk against the limits this station file declares today
        for name, limit in station.effective_limits(part).items():
            if name in series.limits:
                series.limits[name] = Limit(limit.low, limit.high, series.limits[name].unit)
    title = f"part {part}" + (f", station {args.station_id}" if args.station_id else ", every station") + \
        f", latest {len(series)} runs"
    report = build(series, title, args.measurement, args.baseline)
    if getattr(args, "json", False):
        print(json.dumps(to_json(report), default=float))
    else:
        print(format_text(report))
    if args.html:
        from magline.core.reports.spc_page import write_spc_page

        path = write_spc_page(report, Path(args.html))
        print(f"charts written to {path}", file=sys.stderr)
    return 0 if len(series) else 1
