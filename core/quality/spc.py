"""``magline spc``: the process of a part over its latest units, from the results store.

One pass over the store's series (``core/results/series``): an I-MR chart with its run-rule signals
and the capability against the station's limits for each measurement, yield and retry rate per
station, operator and part, refusal causes ranked.  The console prints the text tables
(``format_text``); ``core/reports/spc_page`` draws the same report as charts.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from magline.core.measurements import CATALOGUE, POSSIBLE, base_name
from magline.core.quality.capability import MIN_UNITS, MIN_UNITS_SOURCE, Capability, index_words
from magline.core.quality.charts import ImrChart, frozen_chart, imr_chart
from magline.core.quality.parallel import capabilities
from magline.core.quality.rules import RULES
from magline.core.quality.study import plausibility_note
from magline.core.quality.trends import Shifts, Trends, trends
from magline.core.quality.yields import YieldRow, ranked_causes, yields
from magline.core.results.control_limits import EVERY_STATION, FrozenLimits
from magline.core.results.series import Limit
from magline.core.station.schema import NOT_PROCESS_FIGURES
from magline.core.text import fmt, percent

if TYPE_CHECKING:
    from magline.core.results.series import RunSeries


@dataclass
class MeasurementReport:
    name: str
    unit: str
    limit: Limit
    chart: ImrChart
    capability: Capability
    frozen: FrozenLimits | None = None  # the Phase I limits it is judged against (None: provisional)

    @property
    def limits_from(self) -> str:
        if self.frozen is not None:
            return self.frozen.words()
        return f"provisional: the first {self.chart.baseline} judged units of this window"


@dataclass
class AttributeReport:
    """A count-like or zero-inflated measurement (rejected readings, attempts, warm-up, orientation):
    charted as what it is — the share of units where it happened — not as a normal variable."""

    name: str
    n: int
    units: list[int]  # positions (in the run selection) of the units where it happened
    what: str

    @property
    def proportion(self) -> float:
        return len(self.units) / self.n if self.n else 0.0

    @property
    def ucl(self) -> float:  # a p chart of single units: p̄ + 3·√(p̄(1 − p̄)), never above 1
        p = self.proportion
        return min(1.0, p + 3 * (p * (1 - p)) ** 0.5)


# measurement → (what "happened" means, the test on a value)
ATTRIBUTES = {"rejected_fraction": ("units with readings rejected", lambda v: v > 0),
              "warm_up_fraction": ("units with a warm-up set aside", lambda v: v > 0),
              "attempts": ("units that needed another tumble", lambda v: v > 1)}


# Figures of the station's method, not of the unit: how sure a measurement is (every ``*_sigma_*``), how
# hard the station had to work for it (attempts, readings rejected, a warm-up set aside).  Charted only
# when asked for (``--measurement``); under ``stop: determined`` coverage joins them — the stop rule
# ends each tumble at the coverage it needs, in 1/bins steps, so its spread is the rule's, not the unit's.
STATION_FIGURES = frozenset(NOT_PROCESS_FIGURES) | {"rejected_fraction", "warm_up_fraction"}


def station_figure(name: str, stop_determined: bool = True) -> bool:
    """Is ``name`` (a sensor's or pair's too) a station figure rather than a product characteristic?"""
    base = base_name(name)
    return base in STATION_FIGURES or "_sigma_" in base or (stop_determined and base == "coverage")


@dataclass
class SpcReport:
    title: str
    series: RunSeries
    measurements: list[MeasurementReport] = field(default_factory=list)
    yields: dict[str, list[YieldRow]] = field(default_factory=dict)
    refusals: list[tuple[str, int]] = field(default_factory=list)
    failed: list[tuple[str, int]] = field(default_factory=list)
    constants: list[tuple[str, float, str]] = field(default_factory=list)  # (name, value, unit): not charted
    attributes: list[AttributeReport] = field(default_factory=list)
    missing: list[str] = field(default_factory=list)  # names asked for that these runs do not hold
    station_figures: list[str] = field(default_factory=list)  # not charted by default: the station's, not the unit's
    unlimited: list[str] = field(default_factory=list)  # not charted by default: no limit describes them
    trends: Trends | None = None  # yield and failure causes per day or shift, per station, operator, product, compass
    by_shift: bool = False  # the trends' periods are the line's shifts, not days
    study: Any = None  # what the study is (core/quality/study.py StudyHeader), said before its figures


def _order(name: str) -> tuple[int, str]:
    names = list(CATALOGUE)
    return (names.index(base_name(name)) if base_name(name) in names else len(names), name)


def build(series: RunSeries, title: str, names: Sequence[str] | None = None, baseline: int = 50,
          stop_determined: bool = True, frozen: dict[str, FrozenLimits] | None = None,
          shifts: Shifts | None = None) -> SpcReport:
    """The report of ``series``: the measurements in ``names``, or by default every product
    characteristic — a measurement with a limit that is not a station figure (:func:`station_figure`);
    the others are listed, not charted.  A measurement with ``frozen`` limits is judged against them
    (Phase II); the others get provisional limits from the first ``baseline`` judged units."""
    frozen = frozen or {}
    report = SpcReport(title=title, series=series)
    judged = [i for i, r in enumerate(series.runs) if r["verdict"] in ("pass", "fail")]
    report.missing = [n for n in names or () if n not in series.values]
    charted: list[tuple[str, str, Limit, ImrChart, FrozenLimits | None]] = []
    for name in sorted(names or series.values, key=_order):
        values = series.values.get(name)
        if values is None:
            continue
        limit = series.limits.get(name, Limit(None, None, None))
        if not names and station_figure(name, stop_determined):
            report.station_figures.append(name)
            continue
        if not names and limit.low is None and limit.high is None:
            report.unlimited.append(name)
            continue
        x = values[judged]  # a station fault's run is not the process
        unit = limit.unit or CATALOGUE.get(base_name(name), ("", ""))[0]
        finite = x[np.isfinite(x)]
        if finite.size and np.all(finite == finite[0]):
            report.constants.append((name, float(finite[0]), unit))  # a setting, not a process figure
            continue
        if base_name(name) in ATTRIBUTES:
            what, happened = ATTRIBUTES[base_name(name)]
            present = np.flatnonzero(np.isfinite(x))
            report.attributes.append(AttributeReport(name, int(present.size),
                                                     [judged[i] for i in present if happened(x[i])], what))
            continue
        outside = np.zeros(x.size, bool)
        if limit.low is not None:
            outside |= x < limit.low
        if limit.high is not None:
            outside |= x > limit.high
        bounds = POSSIBLE.get(base_name(name), (-np.inf, np.inf))
        held = frozen.get(name)
        chart = (frozen_chart(name, x, held.centre, held.sigma_within, held.mr_bar, bounds) if held is not None
                 else imr_chart(name, x, baseline, outside, bounds))
        if chart is None:
            continue
        chart.index = [judged[i] for i in chart.index]
        if held is not None:  # the window's units that built the frozen limits, marked as the data behind them
            chart.in_baseline = np.array([in_frozen_baseline(held, series.runs[i], float(value), limit)
                                          for i, value in zip(chart.index, chart.values, strict=True)], bool)
        charted.append((name, unit, limit, chart, held))
    found = capabilities([(chart.values, limit.low, limit.high, chart.sigma) for _, _, limit, chart, _ in charted])
    report.measurements = [MeasurementReport(name=name, unit=unit, limit=limit, chart=chart, capability=cap,
                                             frozen=held)
                           for (name, unit, limit, chart, held), cap in zip(charted, found, strict=True)]
    for by in ("station_id", "operator", "part"):
        report.yields[by] = yields(series, by)
    report.refusals, report.failed = ranked_causes(series)
    report.trends = trends(series, shifts)
    report.by_shift = bool(shifts and shifts.starts)
    return report




def limits_words(report: SpcReport) -> list[str]:
    """Where each chart's centre line and limits come from: frozen (Phase II) or provisional."""
    if not report.measurements:
        return ["no chart: no measurement varies over these units"]
    frozen = sorted({m.frozen.words() for m in report.measurements if m.frozen is not None})
    provisional = [m.name for m in report.measurements if m.frozen is None]
    lines = [f"limits {words} (Phase II: every unit here judged against them)" for words in frozen]
    if provisional:
        first = next(m for m in report.measurements if m.frozen is None).chart.baseline
        lines.append(f"limits PROVISIONAL for {'every chart' if not frozen else ', '.join(provisional)}: from the "
                     f"first {first} judged units of this window, the same units they judge (freeze a baseline: "
                     "magline spc --freeze)")
    return lines


def _ad_p(cap: Capability) -> str:
    return "—" if cap.normality is None else cap.normality.p_words.replace(" ", "")


def in_frozen_baseline(held: FrozenLimits, run: dict, value: float, limit: Limit) -> bool:
    """Whether ``run`` was one of the units a frozen baseline's limits came from: a judged run of the
    baseline's station (or any, for limits frozen over every station) between its first and last run,
    its value inside the measurement's limits (a unit outside them never set a centre line)."""
    if not held.first_run <= int(run["id"]) <= held.last_run or run.get("verdict") not in ("pass", "fail"):
        return False
    if held.station_id != EVERY_STATION and run.get("station_id") != held.station_id:
        return False
    return not ((limit.low is not None and value < limit.low) or (limit.high is not None and value > limit.high))


def format_text(report: SpcReport) -> str:
    runs = report.series.runs
    lines = [report.title,
             f"{len(runs)} runs" + (f", {runs[0]['started']} → {runs[-1]['started']}" if runs else "")
             + (f" (from {report.series.source})" if report.series.source else ""),
             *(report.study.lines() if report.study is not None else []), ""]
    if not runs:
        return "\n".join([*lines, "no runs match"])
    # the indices' columns as wide as their widest entry: a capable process's "538.97 [362.81, 715.13]"
    # pushed the normality columns out of line
    cpk_w = max([20, *(len(index_words(m.capability.cpk)) for m in report.measurements)])
    ppk_w = max([20, *(len(index_words(m.capability.ppk)) for m in report.measurements)])
    header = (f"{'measurement':<24} {'unit':<5} {'n':>6} {'centre':>11} {'σ within':>10} {'LCL':>10} {'UCL':>10} "
              f"{'limits':>18}  {'Cpk [95% CI]':<{cpk_w}} {'Ppk [95% CI]':<{ppk_w}} {'AD p':>6} {'method':<16} "
              "signals")
    lines += [header, "-" * len(header)]
    for m in report.measurements:
        c = m.chart
        limits = f"[{fmt(m.limit.low)}, {fmt(m.limit.high)}]" if m.limit.low is not None or m.limit.high is not None \
            else "no limit"
        latest = c.signals[-1] if c.signals else None
        where = (f"{len(c.signals)}: latest {latest.rule} at {runs[c.index[latest.point]]['serial']}"
                 if latest else "none")
        lines.append(f"{m.name:<24} {m.unit or '—':<5} {c.values.size:>6} {fmt(c.centre):>11} {fmt(c.sigma):>10} "
                     f"{fmt(c.lcl):>10} {fmt(c.ucl):>10} {limits:>18}  {index_words(m.capability.cpk):<{cpk_w}} "
                     f"{index_words(m.capability.ppk):<{ppk_w}} {_ad_p(m.capability):>6} "
                     f"{m.capability.method_short:<16} {where}")
    if report.missing:
        lines.append(f"no run here holds: {', '.join(report.missing)}")
    judged = max((m.capability.n for m in report.measurements), default=0)
    if judged < MIN_UNITS:
        lines.append(f"n = {judged}: capability needs at least {MIN_UNITS} judged units ({MIN_UNITS_SOURCE}); "
                     "Cpk and Ppk are not stated")
    limitless = [m.name for m in report.measurements if m.limit.low is None and m.limit.high is None]
    if limitless:
        lines.append(f"no limit in the station file for {', '.join(limitless)}: charted, but without a limit there "
                     "is no Cpk or Ppk")
    if report.attributes:
        lines += ["", f"{'counted':<24} {'n':>6} {'units':>6} {'share':>7} {'UCL':>7}  what"]
        lines += [f"{a.name:<24} {a.n:>6} {len(a.units):>6} {percent(a.proportion):>7} {percent(a.ucl):>7}  {a.what}"
                  for a in report.attributes]
    if report.constants:
        lines += ["", "constant: " + "; ".join(f"{n} {fmt(v, u)}" for n, v, u in report.constants)]
    if report.station_figures:
        lines += ["", "station figures, not product characteristics (not charted; --measurement NAME charts one): "
                  + ", ".join(report.station_figures)]
    if report.unlimited:
        lines += ["", "no limit in the station file, not charted (--measurement NAME charts one): "
                  + ", ".join(report.unlimited)]
    lines += ["", "rules: " + "; ".join(f"{k} = {v}" for k, v in RULES.items()), *limits_words(report),
              "station faults (error / aborted / incomplete) are not plotted", ""]
    for by, rows in report.yields.items():
        lines.append(f"{'by ' + by.replace('_id', ''):<24} {'runs':>6} {'judged':>7} {'FPY':>7} {'retry rate':>11} "
                     f"{'station faults':>15}")
        for row in rows:
            lines.append(f"  {row.group:<22} {row.runs:>6} {row.judged:>7} {percent(row.fpy):>7} "
                         f"{percent(row.retry_rate):>11} {row.station_faults:>15}")
        lines.append("")
    lines.append("acquisition attempts refused, by cause:")
    lines += [f"  {count:>6}  {cause}" for cause, count in report.refusals] or ["  none"]
    lines.append("measurements that failed units:")
    lines += [f"  {count:>6}  {name}" for name, count in report.failed] or ["  none"]
    lines += _trend_lines(report)
    return "\n".join(lines)


TREND_PERIODS_SHOWN = 14  # the console shows the latest two weeks of days (or shifts); --json holds them all


def _trend_lines(report: SpcReport) -> list[str]:
    """First-pass yield per day or shift (the latest periods) and the compasses failures fell on."""
    t = report.trends
    if t is None or not t.periods:
        return []
    points = next(iter(t.fpy.get("all", {}).values()), [])
    period = "shift" if report.by_shift else "day"
    lines = ["", f"first-pass yield per {period} (latest {min(len(points), TREND_PERIODS_SHOWN)}; failure causes of "
                 "that period):"]
    for p in points[-TREND_PERIODS_SHOWN:]:
        causes = ", ".join(f"{name} {n}" for name, n in t.causes_by_period.get(p.period, Counter()).most_common(3))
        lines.append(f"  {p.period:<26} {p.first_pass:>5} of {p.first_runs:<5} {percent(p.fpy):>7}  {causes}")
    compasses = t.causes_by.get("compass", {})
    if len(compasses) > 1:
        lines.append("failed measurements per compass: "
                     + "; ".join(f"{c} {sum(n.values())}" for c, n in compasses.items()))
    return lines


CSV_COLUMNS = ("measurement", "chart", "serial", "run_id", "started", "value", "moving_range", "in_baseline",
               "centre", "lcl", "ucl", "mr_ucl", "lsl", "usl", "signals")


def csv_rows(report: SpcReport) -> list[dict]:
    """Every charted point with its chart's lines, one row each (``magline spc --csv``): what any chart of
    the report shows, recomputable in a spreadsheet."""
    data = to_json(report)
    rows = []
    for m in data["measurements"]:
        low, high = m.get("limits", [None, None])
        for pt in m["points"]:
            rows.append({"measurement": m["name"], "chart": m["chart"], "serial": pt["serial"], "run_id": pt["run_id"],
                         "started": pt["started"], "value": pt["value"], "moving_range": pt.get("moving_range"),
                         "in_baseline": pt.get("in_baseline"), "centre": m["centre"], "lcl": m["lcl"], "ucl": m["ucl"],
                         "mr_ucl": m.get("mr_ucl"), "lsl": low, "usl": high, "signals": " ".join(pt["signals"])})
    return rows


def to_json(report: SpcReport) -> dict:
    """The report as data (``magline spc --json``) for a spreadsheet or an MES: per measurement its
    chart kind, centre, limits and every signal with the unit's serial."""
    runs = report.series.runs

    def serial(position: int) -> str:
        return runs[position]["serial"]

    def point(chart: ImrChart, k: int, rules: list[str]) -> dict:
        """One plotted unit: which run it is and what the chart makes of it (the MR of the first is None)."""
        run = runs[chart.index[k]]
        return {"serial": run["serial"], "run_id": run["id"], "run_uuid": run.get("run_uuid"),
                "started": str(run["started"]), "value": float(chart.values[k]),
                "moving_range": None if k == 0 else float(abs(chart.values[k] - chart.values[k - 1])),
                "in_baseline": bool(chart.in_baseline[k]) if chart.in_baseline is not None else k < chart.baseline,
                "signals": rules}

    measurements = []
    for m in report.measurements:
        c = m.chart
        signalled: dict[int, list[str]] = {}
        for sig in c.signals:
            signalled.setdefault(sig.point, []).append(sig.rule)
        measurements.append({
            "name": m.name, "unit": m.unit, "n": int(c.values.size), "chart": "I-MR", "centre": c.centre,
            "lcl": c.lcl, "ucl": c.ucl, "sigma_within": c.sigma, "limits": [m.limit.low, m.limit.high],
            "cpk": None if m.capability.cpk is None else vars(m.capability.cpk),
            "ppk": None if m.capability.ppk is None else vars(m.capability.ppk),
            "capability": m.capability.to_dict(), "limits_from": m.limits_from,
            "plausibility": plausibility_note(max((i.value for i in (m.capability.cpk, m.capability.ppk) if i),
                                                  default=None)),
            "frozen": None if m.frozen is None else {"version": m.frozen.version, "frozen_by": m.frozen.frozen_by,
                                                     "frozen_at": m.frozen.frozen_at, "baseline": m.frozen.baseline,
                                                     "station_id": m.frozen.station_id, "n": m.frozen.n,
                                                     "acceptance": m.frozen.acceptance},
            "signals": [{"rule": s.rule, "serial": serial(c.index[s.point]), "value": float(c.values[s.point])}
                        for s in c.signals],
            "baseline": c.baseline, "mr_bar": c.mr_bar, "mr_ucl": c.mr_ucl,
            "points": [point(c, k, signalled.get(k, [])) for k in range(c.values.size)]})
    for a in report.attributes:
        measurements.append({"name": a.name, "n": a.n, "chart": "p (units with any)", "centre": a.proportion,
                             "lcl": 0.0, "ucl": a.ucl, "what": a.what,
                             "units": [serial(i) for i in a.units], "signals": [],
                             "points": [{"serial": runs[i]["serial"], "run_id": runs[i]["id"],
                                         "started": str(runs[i]["started"]), "value": 1.0, "signals": []}
                                        for i in a.units]})
    return {"title": report.title, "runs": len(runs), "measurements": measurements,
            "study": None if report.study is None else report.study.to_dict(),
            "constants": [{"name": n, "value": v, "unit": u} for n, v, u in report.constants],
            "station_figures": report.station_figures, "unlimited": report.unlimited,
            "capability_needs": {"units": MIN_UNITS, "source": MIN_UNITS_SOURCE},
            "missing": report.missing,
            "yields": {by: [vars(r) for r in rows] for by, rows in report.yields.items()},
            "refusals": [{"cause": c, "count": n} for c, n in report.refusals],
            "failed": [{"measurement": n, "count": k} for n, k in report.failed],
            "trends": None if report.trends is None else {"period": "shift" if report.by_shift else "day",
                                                          **report.trends.to_json()}}
