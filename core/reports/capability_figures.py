"""What a quality engineer reads of one characteristic in the batch report (issue 45), after Minitab's
capability sixpack: the I-MR chart by unit time (each point's serial on hover, a click opening the
unit's report), the histogram with the specification limits and the curve the capability was computed
from, and the normal probability plot.  And the failure causes as a Pareto chart (the trends over time
and per group are :mod:`magline.core.reports.trend_figures`').

SVG traces only (Chromium keeps 16 WebGL contexts per page).  Labels of the limits sit inside the plot
area, above their line: on the left edge they overprinted the axis' tick labels ("LSL 0.5").
"""

from __future__ import annotations

import copy
import functools
import math
import os
from collections import Counter
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import plotly.graph_objects as go
from plotly.subplots import make_subplots

from magline.core.quality.capability import Capability
from magline.core.quality.rules import RULES
from magline.core.quality.spc import MeasurementReport, SpcReport
from magline.core.reports.commands import default_name
from magline.core.reports.page import typed_array
from magline.core.text import fmt

LIMIT_COLOUR, LINE_COLOUR = "#cf222e", "#0969da"
BAR_COLOUR, UNIT_COLOUR = "#8c959f", "#8250df"  # histogram bars; the probability plot's unit markers


def report_links(report: SpcReport, folder: Path | None, page: Path) -> dict[int, str]:
    """Run id → the unit report's path relative to the page, for every run whose report exists in
    ``folder`` (the station's ``results.reports``): the page opens them offline."""
    if folder is None or not folder.is_dir():
        return {}
    found = {}
    for run in report.series.runs:
        name = default_name(run)  # the name the station wrote it under
        if (folder / name).is_file():
            found[run["id"]] = Path(os.path.relpath(folder / name, page.parent)).as_posix()
    return found


def imr_figure(m: MeasurementReport, runs: list[dict[str, Any]], links: dict[int, str]) -> dict[str, Any]:
    """The individuals and moving-range chart against unit start time, as the figure's plain JSON (data and
    layout): built through plotly's objects it took 0.1 s a chart, most of it checking every line and label
    again as it was added; the grid is plotly's own (:func:`_imr_grid`)."""
    c = m.chart
    chosen = [runs[i] for i in c.index]
    when = [str(r["started"]) for r in chosen]
    data = [[r["serial"], links.get(r["id"], ""), f"magline report {r['serial']}"] for r in chosen]
    layout = copy.deepcopy(_imr_grid())
    layout["annotations"][0]["text"] = f"{m.name} — individuals ({m.limits_from})"
    traces: list[dict[str, Any]] = [
        {"type": "scatter", "x": when, "y": c.values, "mode": "lines+markers", "name": m.name, "customdata": data,
         "marker": {"size": 5}, "line": {"width": 1}, "xaxis": "x", "yaxis": "y",
         "hovertemplate": "%{customdata[0]}<br>%{x}<br>%{y:.4g}<br><i>click: its report</i><extra></extra>"}]
    flagged = sorted({s.point for s in c.signals})
    if flagged:
        rules: dict[int, list[str]] = {}
        for s in c.signals:
            rules.setdefault(s.point, []).append(RULES[s.rule])
        traces.append({"type": "scatter", "x": [when[p] for p in flagged], "y": c.values[flagged], "mode": "markers",
                       "name": "rule signals", "customdata": [data[p] for p in flagged],
                       "marker": {"color": LIMIT_COLOUR, "size": 9, "symbol": "x"},
                       "text": [f"{data[p][0]}: {'; '.join(rules[p])}" for p in flagged],
                       "hovertemplate": "%{text}<extra></extra>", "xaxis": "x", "yaxis": "y"})
    lines: list[dict] = []  # horizontal lines as plain layout shapes: plotly's add_hline took half the page's time
    notes: list[dict] = []
    for value, label, dash in ((c.centre, "centre", "solid"), (c.ucl, "UCL", "dash"), (c.lcl, "LCL", "dash")):
        _hline(lines, notes, value, 1, LINE_COLOUR, dash, f"{label} {fmt(value)}", "right")
    band = [float(np.min(c.values)), float(np.max(c.values)), *(float(v) for v in (c.lcl, c.ucl, c.centre)
                                                                 if v is not None and np.isfinite(v))]
    low, high = min(band), max(band)
    y_low, y_high, off_scale = view_with_limits(low, high, max(high - low, 1e-9 * max(abs(low), abs(high), 1.0)),
                                                (m.limit.low, m.limit.high))
    for value, label in ((m.limit.low, "LSL"), (m.limit.high, "USL")):
        if value is None:
            continue
        if label in off_scale:
            notes.append(off_scale_note(label, value, value > y_high, "y"))
        else:
            _hline(lines, notes, value, 1, LIMIT_COLOUR, "dot", f"{label} {fmt(value)}", "top left")
    traces.append({"type": "scatter", "x": when[1:], "y": c.moving_ranges, "mode": "lines", "name": "moving range",
                   "line": {"width": 1, "color": "#57606a"}, "xaxis": "x2", "yaxis": "y2"})
    _hline(lines, notes, c.mr_bar, 2, LINE_COLOUR, "solid")
    _hline(lines, notes, c.mr_ucl, 2, LINE_COLOUR, "dash")
    layout["yaxis"].update(range=[y_low, y_high], title={"text": m.unit or ""})
    layout["xaxis2"]["title"] = {"text": "unit start time"}
    layout.update(height=430, margin={"l": 60, "r": 110, "t": 40, "b": 30}, showlegend=False,
                  shapes=[*layout.get("shapes", []), *lines], annotations=[*layout["annotations"], *notes])
    return {"data": traces, "layout": layout}


@functools.cache
def _imr_grid() -> dict[str, Any]:
    """plotly's own layout of the I-MR chart's two rows (shared time axis, 0.68 and 0.32 of the height, the
    rows' titles as its first two annotations), made once: ``make_subplots`` took 30 ms a chart."""
    fig = make_subplots(rows=2, cols=1, shared_xaxes=True, row_heights=[0.68, 0.32], vertical_spacing=0.06,
                        subplot_titles=("individuals", "moving range"))
    return fig.to_plotly_json()["layout"]


def _hline(lines: list[dict], notes: list[dict], value: float | None, row: int, colour: str, dash: str,
           text: str | None = None, where: str = "right") -> None:
    """A horizontal line across subplot ``row`` at ``value`` (and its label at the right edge, or above
    its left end), as plotly's ``add_hline`` draws it."""
    if value is None or not np.isfinite(value):
        return
    axis = "" if row == 1 else str(row)
    lines.append({"type": "line", "xref": f"x{axis} domain", "x0": 0, "x1": 1, "yref": f"y{axis}", "y0": value,
                  "y1": value, "line": {"color": colour, "dash": dash, "width": 1}})
    if text:
        right = where == "right"
        notes.append({"xref": f"x{axis} domain", "yref": f"y{axis}", "x": 1 if right else 0, "y": value,
                      "text": text, "showarrow": False, "xanchor": "left", "yanchor": "middle" if right else "bottom"})


class HistogramView(NamedTuple):
    low: float
    high: float
    bins_start: float


def view_with_limits(low: float, high: float, spread: float, limits: tuple[float | None, float | None],
                     reach: float = 4.0) -> tuple[float, float, set[str]]:
    """An axis range over ``low``–``high`` and half a ``spread`` beyond, stretched to every specification
    limit within ``reach`` spreads of it; the labels of the limits farther away (they are named at the
    edge they lie past, not drawn).  Why: a population 0.1 µT wide under a limit 80 µT away was drawn
    as one flat line — no shape, no control band, labels on top of each other."""
    view_low, view_high = low - 0.5 * spread, high + 0.5 * spread
    off_scale = set()
    for value, label in zip(limits, ("LSL", "USL"), strict=True):
        if value is None:
            continue
        if low - reach * spread <= value <= high + reach * spread:
            view_low, view_high = min(view_low, value - 0.05 * spread), max(view_high, value + 0.05 * spread)
        else:
            off_scale.add(label)
    return view_low, view_high, off_scale


def histogram_view(values: np.ndarray, sigma: float, limits: tuple[float | None, float | None],
                   reach: float = 4.0) -> tuple[HistogramView, float, set[str]]:
    """The x range, the bin width and the limits too far away to draw (:func:`view_with_limits`)."""
    low, high = float(values.min()), float(values.max())
    spread = max(high - low, 6.0 * sigma, 1e-9 * max(abs(low), abs(high), 1.0))
    bins = max(5, min(40, int(math.sqrt(values.size)) + 1))
    size = (high - low) / bins if high > low else spread / 10.0
    view_low, view_high, off_scale = view_with_limits(low, high, spread, limits, reach)
    return HistogramView(view_low, view_high, low - size / 2.0), size, off_scale


def off_scale_note(label: str, value: float, beyond_high: bool, axis: str) -> dict[str, Any]:
    """A limit beyond the view, named at the edge it lies past (x: left/right; y: bottom/top), as an annotation
    of the first plot's area."""
    arrow = {("x", True): "→", ("x", False): "←", ("y", True): "↑", ("y", False): "↓"}[(axis, beyond_high)]
    edge = 1.0 if beyond_high else 0.0
    place = ({"x": edge, "y": 1.0, "xanchor": "right" if beyond_high else "left", "yanchor": "bottom"} if axis == "x"
             else {"x": 0.0, "y": edge, "xanchor": "left", "yanchor": "top" if beyond_high else "bottom"})
    return {"text": f"{label} {fmt(value)} {arrow}", "showarrow": False, "xref": "x domain", "yref": "y domain",
            "font": {"color": LIMIT_COLOUR}, **place}


def fitted_density(cap: Capability, x: np.ndarray) -> np.ndarray | None:
    """The density the capability was computed from, at ``x``: normal, Box-Cox (back-transformed) or
    the shape the percentile method fitted."""
    from scipy import stats

    if cap.method == "percentile":
        return None if cap.shape is None else np.asarray(cap.shape.pdf(x))  # type: ignore[attr-defined]
    if cap.method == "box-cox" and cap.box_cox_lambda is not None and cap.transformed is not None:
        lam = cap.box_cox_lambda
        mean, sigma = cap.transformed
        positive = np.where(x > 0, x, np.nan)
        y = np.log(positive) if abs(lam) < 1e-12 else (positive ** lam - 1) / lam
        return np.nan_to_num(stats.norm.pdf(y, mean, sigma) * positive ** (lam - 1))
    if cap.sigma_overall <= 0:
        return None
    return stats.norm.pdf(x, cap.mean, cap.sigma_overall)


def shape_figure(m: MeasurementReport) -> dict[str, Any]:
    """Histogram with the specification limits and the fitted curve, beside the normal probability plot, as
    the figure's plain JSON (the grid is plotly's own, :func:`_shape_grid`): built through plotly's objects
    each took 40 ms, and a process page draws one per characteristic."""
    from scipy import stats

    values = m.chart.values
    cap = m.capability
    layout = copy.deepcopy(_shape_grid())
    layout["annotations"][0]["text"] = f"histogram — {cap.method_short}"
    view, size, off_scale = histogram_view(values, cap.sigma_overall, (m.limit.low, m.limit.high))
    traces: list[dict[str, Any]] = [
        {"type": "histogram", "x": typed_array(values),
         "xbins": {"start": view.bins_start, "end": view.high, "size": size}, "autobinx": False, "name": "units",
         "marker": {"color": BAR_COLOUR}, "hovertemplate": "%{x}<br>%{y} units<extra></extra>",
         "xaxis": "x", "yaxis": "y"}]
    grid = np.linspace(view.low, view.high, 300)
    density = fitted_density(cap, grid)
    if density is not None:  # scaled as the bars are: units per bin of ``size``
        traces.append({"type": "scatter", "x": typed_array(grid), "y": typed_array(density * values.size * size),
                       "mode": "lines",
                       "name": "fitted", "line": {"color": LINE_COLOUR, "width": 2}, "xaxis": "x", "yaxis": "y"})
    lines: list[dict[str, Any]] = []
    for value, label in ((m.limit.low, "LSL"), (m.limit.high, "USL")):
        if value is None:
            continue
        if label in off_scale:  # far from every unit: named at the edge it lies beyond, not drawn as a spike
            layout["annotations"].append(off_scale_note(label, value, value > view.high, "x"))
        else:  # a vertical line over the histogram's height, labelled above it, as plotly's add_vline draws it
            lines.append({"type": "line", "xref": "x", "x0": value, "x1": value, "yref": "y domain", "y0": 0,
                          "y1": 1, "line": {"color": LIMIT_COLOUR, "dash": "dot", "width": 1.5}})
            layout["annotations"].append({"text": f"{label} {fmt(value)}", "showarrow": False, "xref": "x",
                                          "x": value, "xanchor": "center", "yref": "y domain", "y": 1,
                                          "yanchor": "bottom"})
    (theoretical, ordered), (slope, intercept, _) = stats.probplot(values, dist="norm")
    traces.append({"type": "scatter", "x": typed_array(theoretical), "y": typed_array(ordered), "mode": "markers",
                   "name": "units", "marker": {"size": 6, "color": UNIT_COLOUR},
                   "hovertemplate": "z %{x:.2f}<br>%{y:.4g}<extra></extra>", "xaxis": "x2", "yaxis": "y2"})
    traces.append({"type": "scatter", "x": [theoretical[0], theoretical[-1]],
                   "y": [slope * theoretical[0] + intercept, slope * theoretical[-1] + intercept], "mode": "lines",
                   "name": "normal", "line": {"color": LINE_COLOUR, "width": 1}, "xaxis": "x2", "yaxis": "y2"})
    layout["xaxis"].update(range=[view.low, view.high], title={"text": m.unit or ""})
    layout["xaxis2"]["title"] = {"text": "normal quantile"}
    layout["yaxis"]["title"] = {"text": "units"}
    layout["yaxis2"]["title"] = {"text": m.unit or ""}
    layout.update(height=320, margin={"l": 60, "r": 30, "t": 50, "b": 40}, showlegend=False, bargap=0.04)
    if lines:
        layout["shapes"] = [*layout.get("shapes", []), *lines]
    return {"data": traces, "layout": layout}


@functools.cache
def _shape_grid() -> dict[str, Any]:
    """plotly's own layout of the histogram beside the probability plot (0.55 and 0.45 of the width, the
    plots' titles as its first two annotations), made once."""
    fig = make_subplots(rows=1, cols=2, column_widths=[0.55, 0.45], horizontal_spacing=0.1,
                        subplot_titles=("histogram", "normal probability plot"))
    return fig.to_plotly_json()["layout"]


def capability_rows(m: MeasurementReport) -> list[tuple[str, str]]:
    """The capability summary of one characteristic, as (name, words)."""
    cap = m.capability
    return [("units", str(cap.n)), ("mean", fmt(cap.mean, m.unit)),
            ("σ within (MR̄ / d₂)", fmt(cap.sigma_within, m.unit)), ("σ overall", fmt(cap.sigma_overall, m.unit)),
            ("limits", f"[{fmt(m.limit.low)}, {fmt(m.limit.high)}]"),
            ("Cpk [95 % CI]", cap.cpk.words() if cap.cpk else "—"),
            ("Ppk [95 % CI]", cap.ppk.words() if cap.ppk else "—"),
            ("shape and method", cap.method_words), ("control limits", m.limits_from)]


def failure_pareto(report: SpcReport) -> go.Figure | None:
    """The measurements that failed units, most frequent first, with the cumulative share."""
    counts = Counter(dict(report.failed))
    if not counts:
        return None
    names = [n for n, _ in counts.most_common()]
    values = [counts[n] for n in names]
    cumulative = np.cumsum(values) / sum(values) * 100.0
    fig = make_subplots(specs=[[{"secondary_y": True}]])
    fig.add_trace(go.Bar(x=names, y=values, name="units failed", marker={"color": LIMIT_COLOUR}), secondary_y=False)
    fig.add_trace(go.Scatter(x=names, y=cumulative, mode="lines+markers", name="cumulative %",
                             line={"color": "#57606a"}), secondary_y=True)
    fig.update_layout(title="failure causes (Pareto)", height=300, margin={"l": 60, "r": 60, "t": 50, "b": 80})
    fig.update_yaxes(title_text="units", secondary_y=False)
    fig.update_yaxes(title_text="cumulative %", range=[0, 105], secondary_y=True)
    return fig


CLICK_SCRIPT = """<script>
document.addEventListener('plotted', function (drawn) {
  var plot = drawn.target;
  if (!plot.closest('.imr-chart')) return;
  plot.on('plotly_click', function (event) {
    var data = event.points[0].customdata;
    if (!data) return;
    if (data[1]) { window.location.href = data[1]; }
    else { alert(data[0] + ': no report file beside this page yet; write it with ' + data[2]); }
  });
});
</script>"""
