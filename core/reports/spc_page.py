"""The batch report: ``magline spc --html``'s control charts, capability and yield as one page."""

from __future__ import annotations

import html
from pathlib import Path

import numpy as np
import plotly.graph_objects as go
from plotly.subplots import make_subplots

from magline.core.quality.capability import MIN_UNITS, MIN_UNITS_SOURCE, index_words
from magline.core.quality.rules import RULES
from magline.core.quality.spc import MeasurementReport, SpcReport
from magline.core.reports.page import figure_html, table, write_page
from magline.core.text import fmt, percent


def _chart(m: MeasurementReport, serials: list[str]) -> go.Figure:
    """SVG traces, not WebGL: Chromium keeps at most 16 WebGL contexts per page (the oldest charts lose
    their points beyond that), and each costs a second to start under software rendering."""
    c = m.chart
    x = np.arange(1, c.values.size + 1)
    names = [serials[i] for i in c.index]
    fig = make_subplots(rows=2, cols=1, shared_xaxes=True, row_heights=[0.68, 0.32], vertical_spacing=0.06,
                        subplot_titles=(f"{m.name} — individuals", "moving range"))
    fig.add_trace(go.Scatter(x=x, y=c.values, mode="lines+markers", name=m.name, text=names,
                               marker={"size": 4}, line={"width": 1},
                               hovertemplate="%{text}<br>%{y:.4g}<extra></extra>"), row=1, col=1)
    flagged = sorted({s.point for s in c.signals})
    if flagged:
        rules = {}
        for s in c.signals:
            rules.setdefault(s.point, []).append(RULES[s.rule])
        fig.add_trace(go.Scatter(x=x[flagged], y=c.values[flagged], mode="markers", name="rule signals",
                                   marker={"color": "#cf222e", "size": 8, "symbol": "x"},
                                   text=[f"{names[p]}: {'; '.join(rules[p])}" for p in flagged],
                                   hovertemplate="%{text}<extra></extra>"), row=1, col=1)
    for value, label, dash in ((c.centre, "centre", "solid"), (c.ucl, "UCL", "dash"), (c.lcl, "LCL", "dash")):
        fig.add_hline(y=value, line={"color": "#0969da", "dash": dash, "width": 1}, row=1, col=1,
                      annotation_text=f"{label} {fmt(value)}", annotation_position="right")
    for value, label in ((m.limit.low, "LSL"), (m.limit.high, "USL")):
        if value is not None:
            fig.add_hline(y=value, line={"color": "#cf222e", "dash": "dot", "width": 1}, row=1, col=1,
                          annotation_text=f"{label} {fmt(value)}", annotation_position="left")
    fig.add_trace(go.Scatter(x=x[1:], y=c.moving_ranges, mode="lines", name="moving range",
                               line={"width": 1, "color": "#57606a"}), row=2, col=1)
    fig.add_hline(y=c.mr_bar, line={"color": "#0969da", "width": 1}, row=2, col=1)
    fig.add_hline(y=c.mr_ucl, line={"color": "#0969da", "dash": "dash", "width": 1}, row=2, col=1)
    fig.update_layout(height=430, margin={"l": 60, "r": 110, "t": 40, "b": 30}, showlegend=False)
    fig.update_yaxes(title_text=m.unit or "", row=1, col=1)
    fig.update_xaxes(title_text="unit (oldest first)", row=2, col=1)
    return fig


def write_spc_page(report: SpcReport, path: Path) -> Path:
    serials = [r["serial"] for r in report.series.runs]
    sections = [f"<h1>Process control — {html.escape(report.title)}</h1>",
                f"<p class=note>{len(serials)} runs"
                + (f", {html.escape(report.series.runs[0]['started'])} → "
                   f"{html.escape(report.series.runs[-1]['started'])}" if serials else "")
                + (f"; from {html.escape(report.series.source)}" if report.series.source else "")
                + ". Centre line and 3σ limits from the first judged units (baseline); rules: "
                + html.escape("; ".join(RULES.values())) + ".</p>"]

    rows = [(m.name, m.chart.values.size, fmt(m.chart.centre, m.unit), fmt(m.chart.sigma, m.unit),
             f"[{fmt(m.limit.low)}, {fmt(m.limit.high)}]", index_words(m.capability.cpk),
             index_words(m.capability.ppk), m.capability.method_words, len(m.chart.signals))
            for m in report.measurements]
    sections += ["<h2>Capability</h2>",
                 table(("measurement", "n", "centre", "σ within", "limits", "Cpk [95% CI]", "Ppk [95% CI]",
                        "shape and method", "rule signals"), rows, numeric=(1, 2, 3, 8))]
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
    sections.append("<h2>Control charts</h2>")
    sections += [figure_html(_chart(m, serials), f"chart-{m.name}") for m in report.measurements]
    return write_page(path, f"magline spc — {report.title}", sections)
