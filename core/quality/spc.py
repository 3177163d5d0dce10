"""``magline spc``: the process of a part over its latest units, from the results store.

One pass over the store's series (``core/results/series``): an I-MR chart with its run-rule signals
and the capability against the station's limits for each measurement, yield and retry rate per
station, operator and part, refusal causes ranked.  The console prints the text tables
(``format_text``); ``core/reports/spc_page`` draws the same report as charts.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

from magline.core.measurements import CATALOGUE
from magline.core.quality.capability import Capability, capability
from magline.core.quality.charts import ImrChart, imr_chart
from magline.core.quality.rules import RULES
from magline.core.quality.yields import YieldRow, ranked_causes, yields
from magline.core.results.series import Limit, RunSeries
from magline.core.text import fmt, percent


@dataclass
class MeasurementReport:
    name: str
    unit: str
    limit: Limit
    chart: ImrChart
    capability: Capability


@dataclass
class SpcReport:
    title: str
    series: RunSeries
    measurements: list[MeasurementReport] = field(default_factory=list)
    yields: dict[str, list[YieldRow]] = field(default_factory=dict)
    refusals: list[tuple[str, int]] = field(default_factory=list)
    failed: list[tuple[str, int]] = field(default_factory=list)


def _order(name: str) -> tuple[int, str]:
    names = list(CATALOGUE)
    return (names.index(name) if name in names else len(names), name)


def build(series: RunSeries, title: str, names: Sequence[str] | None = None, baseline: int = 50) -> SpcReport:
    report = SpcReport(title=title, series=series)
    judged = [i for i, r in enumerate(series.runs) if r["verdict"] in ("pass", "fail")]
    for name in sorted(names or series.values, key=_order):
        values = series.values.get(name)
        if values is None:
            continue
        chart = imr_chart(name, values[judged], baseline)  # a station fault's run is not the process
        if chart is None:
            continue
        limit = series.limits.get(name, Limit(None, None, None))
        chart.index = [judged[i] for i in chart.index]
        report.measurements.append(MeasurementReport(
            name=name, unit=limit.unit or CATALOGUE.get(name, ("", ""))[0], limit=limit, chart=chart,
            capability=capability(chart.values, limit.low, limit.high, chart.sigma)))
    for by in ("station_id", "operator", "part"):
        report.yields[by] = yields(series, by)
    report.refusals, report.failed = ranked_causes(series)
    return report


def _interval(index: object) -> str:
    if index is None:
        return "—"
    return f"{index.value:.2f} [{index.low:.2f}, {index.high:.2f}]"


def format_text(report: SpcReport) -> str:
    runs = report.series.runs
    lines = [report.title,
             f"{len(runs)} runs" + (f", {runs[0]['started']} → {runs[-1]['started']}" if runs else "")
             + (f" (from {report.series.source})" if report.series.source else ""), ""]
    if not runs:
        return "\n".join([*lines, "no runs match"])
    header = (f"{'measurement':<24} {'n':>6} {'centre':>11} {'σ within':>10} {'LCL':>10} {'UCL':>10} "
              f"{'limits':>18}  {'Cpk [95% CI]':<20} {'Ppk [95% CI]':<20} signals")
    lines += [header, "-" * len(header)]
    for m in report.measurements:
        c = m.chart
        limits = f"[{fmt(m.limit.low)}, {fmt(m.limit.high)}]" if m.limit.low is not None or m.limit.high is not None \
            else "no limit"
        latest = c.signals[-1] if c.signals else None
        where = (f"{len(c.signals)}: latest {latest.rule} at {runs[c.index[latest.point]]['serial']}"
                 if latest else "none")
        lines.append(f"{m.name:<24} {c.values.size:>6} {fmt(c.centre):>11} {fmt(c.sigma):>10} {fmt(c.lcl):>10} "
                     f"{fmt(c.ucl):>10} {limits:>18}  {_interval(m.capability.cpk):<20} "
                     f"{_interval(m.capability.ppk):<20} {where}")
    lines += ["", "rules: " + "; ".join(f"{k} = {v}" for k, v in RULES.items()),
              "limits from the first " + (f"{report.measurements[0].chart.baseline}" if report.measurements else "—")
              + " judged units (baseline); station faults (error / aborted / incomplete) are not plotted", ""]
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
    return "\n".join(lines)
