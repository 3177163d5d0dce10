"""The batch report: ``magline spc --html``'s control charts, capability and yield as one page."""

from __future__ import annotations

import html
import os
import re
from pathlib import Path

from magline.core.quality.capability import MIN_UNITS, MIN_UNITS_SOURCE, index_words
from magline.core.quality.rules import RULES
from magline.core.quality.spc import SpcReport
from magline.core.quality.study import plausibility_note
from magline.core.reports.capability_figures import (
    CLICK_SCRIPT,
    capability_rows,
    failure_pareto,
    imr_figure,
    report_links,
    shape_figure,
)
from magline.core.reports.page import figure_html, table, write_page
from magline.core.reports.trend_figures import causes_by, causes_over_time, yield_over_time
from magline.core.text import fmt, percent


def page_words(source: str) -> str:
    """A sentence of the page with this computer's files by their names (the store it was drawn from, the
    station file): the page is mailed and opened on other computers, where this one's folders mean
    nothing; a server is named as it is."""
    return re.sub(r"(?<!\S)/(?:[^\s/()]+/)+([^\s/()]+)", r"\1", source)


def _beside(folder: Path, page: Path) -> str:
    """The reports folder as the page's links reach it: relative to the page."""
    return os.path.relpath(folder.resolve(), page.resolve().parent)


def write_spc_page(report: SpcReport, path: Path, reports: Path | None = None, *,
                   plotly_src: str | None = None) -> Path:
    """The page; ``reports``: the station's unit-report folder, whose files a click on a point opens
    (``plotly_src``: as :func:`~magline.core.reports.page.write_page`)."""
    title, sections = spc_sections(report, report_links(report, reports, path),
                                   _beside(reports, path) if reports else None)
    return write_page(path, title, sections, plotly_src)


def spc_sections(report: SpcReport, links: dict[int, str], reports_from: str | None = None) -> tuple[str, list[str]]:
    """The page's title and sections; ``links``: run id → the address a click on its point opens (a report
    file beside the page, or the dashboard's own address); ``reports_from``: where those files are, in the
    page's words."""
    serials = [r["serial"] for r in report.series.runs]
    sections = [f"<h1>Process control — {html.escape(report.title)}</h1>",
                f"<p class=note>{len(serials)} runs"
                + (f", {html.escape(report.series.runs[0]['started'])} → "
                   f"{html.escape(report.series.runs[-1]['started'])}" if serials else "")
                + (f"; from {html.escape(page_words(report.series.source))}" if report.series.source else "")
                + ". Centre line and 3σ limits from the first judged units (baseline); rules: "
                + html.escape("; ".join(RULES.values())) + ".</p>"]
    if report.study is not None:  # what the study is, before its figures
        first, *rest = report.study.lines()
        warn = " style='color:#b00;font-weight:bold'" if report.study.repeatability else ""
        sections += [f"<h2{warn}>{html.escape(first.removeprefix('study: '))}</h2>",
                     "<ul class=study>" + "".join(f"<li>{html.escape(page_words(line))}</li>" for line in rest)
                     + "</ul>"]

    rows = [(m.name, m.chart.values.size, fmt(m.chart.centre, m.unit), fmt(m.chart.sigma, m.unit),
             f"[{fmt(m.limit.low)}, {fmt(m.limit.high)}]", index_words(m.capability.cpk),
             index_words(m.capability.ppk), "; ".join(filter(None, (m.capability.method_words, plausibility_note(
                 max((i.value for i in (m.capability.cpk, m.capability.ppk) if i), default=None))))),
             len(m.chart.signals))
            for m in report.measurements]
    sections += ["<h2>Capability</h2>",
                 table(("measurement", "n", "centre", "σ within", "limits", "Cpk [95% CI]", "Ppk [95% CI]",
                        "shape and method", "rule signals"), rows, numeric=(1, 2, 3, 4, 5, 6, 8))]
    judged = max((m.capability.n for m in report.measurements), default=0)
    if judged < MIN_UNITS:
        sections.append(f"<p class=note>n = {judged}: capability needs at least {MIN_UNITS} judged units "
                        f"({html.escape(MIN_UNITS_SOURCE)}); Cpk and Ppk are not stated.</p>")
    if report.attributes:
        sections += ["<h2>Counted per unit</h2>",
                     table(("measurement", "n", "units", "share", "UCL", "what"),
                           [(a.name, a.n, len(a.units), percent(a.proportion), percent(a.ucl), a.what)
                            for a in report.attributes], numeric=(1, 2, 3, 4))]
    if report.constants:
        sections.append("<p>constant: " + html.escape("; ".join(f"{n} {fmt(v, u)}" for n, v, u in report.constants))
                        + "</p>")
    if report.station_figures:
        sections.append("<p>station figures, not product characteristics (not charted; <code>--measurement NAME</code> "
                        "charts one): " + html.escape(", ".join(report.station_figures)) + "</p>")
    if report.unlimited:
        sections.append("<p>no limit in the station file, not charted: " + html.escape(", ".join(report.unlimited))
                        + "</p>")
    sections.append("<h2>Yield</h2>")
    for by, yrows in report.yields.items():
        sections.append(table((by.replace("_id", ""), "runs", "judged", "first-pass yield", "retry rate",
                               "station faults"),
                              [(r.group, r.runs, r.judged, percent(r.fpy), percent(r.retry_rate), r.station_faults)
                               for r in yrows], numeric=(1, 2, 3, 4, 5)))
    sections += ["<h2>Causes</h2>",
                 table(("acquisition attempts refused, by cause", "count"), report.refusals or [("none", 0)],
                       numeric=(1,)),
                 table(("measurements that failed units", "count"), report.failed or [("none", 0)], numeric=(1,))]
    sections += _trend_sections(report)
    sections.append("<h2>Characteristics</h2><p class=note>each point is a unit (hover: its serial; click: its "
                    "report" + (", from " + html.escape(reports_from) if reports_from else "") + ")</p>")
    for m in report.measurements:
        sections += [f"<h3>{html.escape(m.name)}</h3>",
                     f"<div class=imr-chart>{figure_html(imr_figure(m, report.series.runs, links), f'chart-{m.name}')}"
                     "</div>",
                     figure_html(shape_figure(m), f"shape-{m.name}"), table(None, capability_rows(m))]
    sections.append(CLICK_SCRIPT)
    return f"magline spc — {report.title}", sections


def _trend_sections(report: SpcReport) -> list[str]:
    """Yield and failure causes over time, then split by station, operator, product and compass."""
    if report.trends is None:
        return []
    t, by_shift = report.trends, report.by_shift
    over_time = [(yield_over_time(t, "all", by_shift), "fpy-over-time"),
                 (causes_over_time(t, by_shift), "causes-over-time"), (failure_pareto(report), "pareto")]
    split = [(yield_over_time(t, word, by_shift), f"fpy-per-{word}") for word in ("station", "operator", "product")]
    split += [(causes_by(t, word), f"causes-per-{word}") for word in ("station", "operator", "product", "compass")]
    out = []
    if any(fig is not None for fig, _ in over_time):
        out += ["<h2>Over time</h2>", *(figure_html(fig, name) for fig, name in over_time if fig is not None)]
    if any(fig is not None for fig, _ in split):
        out += ["<h2>Per station, operator, product and compass</h2>",
                *(figure_html(fig, name) for fig, name in split if fig is not None)]
    return out
