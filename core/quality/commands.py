"""``magline spc``: read a part's latest units from the store, print the tables, write the page."""

from __future__ import annotations

import argparse
import csv
import json
import sys
from collections.abc import Iterable
from difflib import get_close_matches
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from magline.core.faults import StationFault
from magline.core.measurements import CATALOGUE, base_name, known_limit_name
from magline.core.quality.baseline import (
    Acceptance,
    BaselineRefused,
    BaselineUnstable,
    baseline_words,
    freeze_baseline,
    frozen_text,
)
from magline.core.quality.spc import CSV_COLUMNS, build, csv_rows, format_text, to_json
from magline.core.results.contract import KeepsSeries, ReadsInSql
from magline.core.results.control_limits import newest
from magline.core.results.reading import RunFilter
from magline.core.results.series import Limit

if TYPE_CHECKING:
    from magline.core.results.series import RunSeries
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


def _with_station_limits(series: RunSeries, station: Station, part: str) -> RunSeries:
    """Cpk against the limits this station file declares today (where it declares the part)."""
    if part in station.products:
        for name, limit in station.effective_limits(part).items():
            if name in series.limits:
                series.limits[name] = Limit(limit.low, limit.high, series.limits[name].unit)
    return series


def _freeze(store: Any, station: Station, part: str, args: argparse.Namespace, stop_determined: bool) -> int:
    """Phase I: the baseline's units alone, every point in it; its limits stored (see core/quality/baseline)."""
    if not isinstance(store, ReadsInSql):
        raise StationFault("this station's results store keeps no control limits: --freeze needs a SQL store")
    by_date = args.baseline_since is not None or args.baseline_until is not None
    first = None if by_date else args.baseline
    words = baseline_words(first, args.baseline_since, args.baseline_until)
    where = RunFilter(part=part, station_id=args.station_id, since=args.baseline_since, until=args.baseline_until,
                      verdicts=("pass", "fail"))
    if not (args.by or "").strip():
        print("--freeze needs --by NAME: who is responsible for the limits frozen", file=sys.stderr)
        return 2
    if args.accept_unstable and not (args.reason or "").strip():
        print("--accept-unstable needs --reason \"…\": why limits from an unstable baseline may judge later units",
              file=sys.stderr)
        return 2
    excluded = tuple(dict.fromkeys(s.strip().upper() for s in args.exclude or () if s.strip()))
    series = _without(_with_station_limits(store.series(where, names=args.measurement, first=first), station, part),
                      excluded)
    if excluded:
        words += f", {', '.join(excluded)} left out"
    report = build(series, f"baseline of part {part}", args.measurement, baseline=max(len(series), 1),
                   stop_determined=stop_determined)
    accepted = Acceptance(by=args.by.strip(), excluded=excluded, accept_unstable=args.accept_unstable,
                          reason=(args.reason or "").strip())
    try:
        frozen = freeze_baseline(store.engine, report, part, args.station_id, words, accepted)
    except BaselineUnstable as exc:
        print(str(exc), file=sys.stderr)
        return 1
    except BaselineRefused as exc:
        print(str(exc), file=sys.stderr)
        return 2
    print(frozen_text(frozen, part, args.station_id))
    return 0


def _study(store: Any, station: Station, part: str, args: argparse.Namespace, series: Any, frozen: dict) -> Any:
    """What the study is (core/quality/study.py): the station file's product and reference, the limit sets
    the runs were judged against, who froze the limits in use, the window asked, the boards behind it."""
    from magline.core.quality.study import StudyHeader, count_boards
    from magline.core.results.reading import params_by_stage

    runs = series.runs
    hashes = list(dict.fromkeys(str(r.get("limit_hash") or "—") for r in reversed(runs)))
    source = station.field_source
    reference = f"{source.type} field source" + "".join(
        f", {k} {v}" for k, v in (source.options or {}).items() if k in ("field_ut", "inclination_deg", "model"))
    fields = [float(r["reference_field_ut"]) for r in runs if r.get("reference_field_ut") is not None]
    if fields:  # what the units were really measured against (a fluxgate's checks move it)
        reference += (f"; the runs measured against {min(fields):.2f}–{max(fields):.2f} µT" if max(fields) > min(fields)
                      else f"; the runs measured against {fields[0]:.2f} µT")
    by = sorted({f.frozen_by for f in frozen.values() if f.frozen_by})
    boards = None
    if isinstance(store, ReadsInSql):
        ids = [int(r["id"]) for r in runs]
        with store.engine.connect() as conn:
            boards = count_boards(params_by_stage(conn, ids), ids)
    window = ", ".join(f"{k} {v}" for k, v in (("since", args.since), ("until", args.until)) if v) or "every run"
    revisions = list(dict.fromkeys(str(r.get("station_hash") or "—")[:12] for r in reversed(runs)))
    station_file = str(args.station or "the embedded demo station") + f", revision {revisions[0]}" + (
        f" ({len(revisions)} revisions in the window)" if len(revisions) > 1 else "")
    return StudyHeader(product=part, station_file=station_file,
                       specification="limit set " + ", ".join(hashes[:3]) + (" …" if len(hashes) > 3 else "")
                       + f" ({len(hashes)} in the window)", reference=reference,
                       responsible=(f"limits frozen by {', '.join(by)}" if by else
                                    "nobody yet: the limits are provisional (spc --freeze --by NAME)"),
                       window=f"{window}, the latest {args.last} at most", points=len(runs),
                       units=len({str(r['serial']).upper() for r in runs}), boards=boards)


def _without(series: Any, serials: tuple[str, ...]) -> Any:
    """The series with the runs of ``serials`` (any case) left out."""
    if not serials:
        return series
    keep = [i for i, run in enumerate(series.runs) if str(run.get("serial", "")).strip().upper() not in serials]
    series.runs = [series.runs[i] for i in keep]
    series.values = {name: np.asarray(values)[keep] for name, values in series.values.items()}
    return series


def unknown_measurements(names: list[str] | None, declared: Iterable[str] = ()) -> str | None:
    """Why ``--measurement`` names no measurement magline or a plugin (``declared``) makes (a sentence,
    with the nearest names), or None when every name is one."""
    declared = set(declared)
    known = [*CATALOGUE, *sorted(declared)]
    unknown = [n for n in names or () if not known_limit_name(n) and base_name(n) not in declared]
    if not unknown:
        return None
    hints = [f"{n} (did you mean {close[0]}?)" if (close := get_close_matches(base_name(n), known, 1)) else n
             for n in unknown]
    return f"--measurement: no measurement is called {', '.join(hints)}; magline measures: {', '.join(known)}"


def spc(store: Any, station: Station, args: argparse.Namespace, station_dir: Path | None = None,
        declared: Iterable[str] = ()) -> int:
    """``magline spc``: ``declared`` are the loaded plugins' own measurement names (``--measurement`` may
    name them)."""
    if not isinstance(store, KeepsSeries):
        raise StationFault("this station's results sink keeps no history: spc reads SQL stores only")
    unknown = unknown_measurements(args.measurement, declared)
    if unknown:
        print(unknown, file=sys.stderr)
        return 2
    part = part_of(station, args.part)
    stop_determined = station.acquisition.stop == "determined"
    if getattr(args, "freeze", False):
        return _freeze(store, station, part, args, stop_determined)
    where = RunFilter(part=part, station_id=args.station_id, since=args.since, until=args.until)
    series = _with_station_limits(store.series(where, last=args.last, names=args.measurement, with_attempts=True),
                                  station, part)
    if not len(series):
        window = "".join(f" {name} {value}" for name, value in (("since", args.since), ("until", args.until)) if value)
        print(f"no runs of part {part}" + (f" at station {args.station_id}" if args.station_id else "")
              + f"{window} in {series.source or 'the results store'}: nothing to chart (no page, no data written)",
              file=sys.stderr)
        return 2
    title = f"part {part}" + (f", station {args.station_id}" if args.station_id else ", every station") + \
        f", latest {len(series)} runs"
    frozen = {}
    if isinstance(store, ReadsInSql):
        with store.engine.connect() as conn:
            frozen = newest(conn, part, args.station_id)
    if getattr(args, "with_reports", False) and not args.html:
        print("--with-reports writes the reports a page's points open: give --html FILE too", file=sys.stderr)
        return 2
    report = build(series, title, args.measurement, args.baseline, stop_determined=stop_determined, frozen=frozen,
                   shifts=getattr(args, "shifts", None))
    report.study = _study(store, station, part, args, series, frozen)
    if getattr(args, "json", False):
        print(json.dumps(to_json(report), default=float))
    elif getattr(args, "csv", False):
        out = csv.DictWriter(sys.stdout, fieldnames=CSV_COLUMNS, lineterminator="\n")
        out.writeheader()
        out.writerows(csv_rows(report))
    else:
        print(format_text(report))
    if args.html:
        from magline.core.reports.commands import write_missing_reports
        from magline.core.reports.spc_page import write_spc_page

        page = Path(args.html)
        folder = station.main_results.reports
        reports = station_dir / folder if folder and station_dir else None
        if getattr(args, "with_reports", False):
            if not isinstance(store, ReadsInSql):
                raise StationFault("this station's results sink is not a SQL store: reports read SQL stores only")
            reports = reports or page.with_name(page.stem + "-reports")
            charted = sorted({i for m in report.measurements for i in m.chart.index}
                             | {i for a in report.attributes for i in a.units})
            written = write_missing_reports(store.engine, [series.runs[i] for i in charted], reports)
            print(f"{len(written)} unit report(s) written to {reports} ({len(charted) - len(written)} were there)",
                  file=sys.stderr)
        path = write_spc_page(report, page, reports)
        print(f"charts written to {path}", file=sys.stderr)
    return 0
