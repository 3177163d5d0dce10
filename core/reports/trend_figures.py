"""The batch page's trends: first-pass yield per day or shift (all units, then per station, operator
and product where there is more than one), and the failure causes over time and stacked by station,
operator, product and compass.  The numbers are :mod:`magline.core.quality.trends`'s, which
``spc --json`` carries too.

SVG traces only (Chromium keeps 16 WebGL contexts per page).
"""

from __future__ import annotations

import plotly.graph_objects as go
from plotly.subplots import make_subplots

from magline.core.quality.trends import Trends

MARGIN = {"l": 60, "r": 60, "t": 50, "b": 90}
PERIOD_WORD = {True: "shift", False: "day"}


MARKER_SYMBOLS = ("circle", "diamond", "square", "triangle-up", "x", "cross")


def yield_over_time(trends: Trends, grouping: str, by_shift: bool) -> go.Figure | None:
    """FPY per period for every group of ``grouping`` (``all``: with the judged first runs as bars);
    None where the grouping has a single group (the ``all`` figure says it already)."""
    groups = trends.fpy.get(grouping, {})
    if not groups or (grouping != "all" and len(groups) < 2):
        return None
    period = PERIOD_WORD[by_shift]
    fig = make_subplots(specs=[[{"secondary_y": True}]])
    if grouping == "all":
        (points,) = groups.values()
        fig.add_trace(go.Bar(x=[p.period for p in points], y=[p.first_runs for p in points],
                             name="first runs judged", marker={"color": "#d0d7de"}), secondary_y=False)
    for rank, (group, points) in enumerate(groups.items()):
        # each group's markers a size smaller and of their own symbol, drawn over the one before: two groups
        # at the same yield in a period (carol's 100 % under dave's) both stay visible
        fig.add_trace(go.Scatter(
            x=[p.period for p in points], y=[100.0 * p.first_pass / p.first_runs for p in points],
            marker={"size": max(14 - 3 * rank, 5), "symbol": MARKER_SYMBOLS[rank % len(MARKER_SYMBOLS)]},
            mode="lines+markers", name=f"FPY {group}" if grouping != "all" else "first-pass yield",
            customdata=[[p.first_pass, p.first_runs] for p in points],
            hovertemplate=f"{group}<br>%{{x}}<br>FPY %{{y:.1f}} % (%{{customdata[0]}} of %{{customdata[1]}})"
                          "<extra></extra>"), secondary_y=True)
    title = f"first-pass yield per {period}" + ("" if grouping == "all" else f", per {grouping}")
    fig.update_layout(title=title, height=320, margin=MARGIN)
    fig.update_yaxes(title_text="units", secondary_y=False, visible=grouping == "all")
    # its own ticks at round percentages: aligned to the units axis they fell at 33.3, 66.5, 99.8
    fig.update_yaxes(title_text="FPY %", range=[0, 105], tickvals=[0, 25, 50, 75, 100], showgrid=False,
                     secondary_y=True)
    fig.update_xaxes(type="category")
    return fig


def causes_over_time(trends: Trends, by_shift: bool) -> go.Figure | None:
    """Units failed per period, stacked by the measurement that failed them."""
    if not trends.causes:
        return None
    periods = [p for p in trends.periods if p in trends.causes_by_period]
    fig = go.Figure([go.Bar(x=periods, y=[trends.causes_by_period[p][cause] for p in periods], name=cause)
                     for cause in trends.causes])
    fig.update_layout(barmode="stack", title=f"failure causes per {PERIOD_WORD[by_shift]}", height=320,
                      margin=MARGIN, yaxis_title="units failed")
    fig.update_xaxes(type="category")
    return fig


def causes_by(trends: Trends, grouping: str) -> go.Figure | None:
    """The failure causes (most frequent first) stacked by the groups of ``grouping``; None where all
    failures fall in one group (the overall Pareto says it already) or none failed."""
    groups = trends.causes_by.get(grouping, {})
    if len(groups) < 2:
        return None
    fig = go.Figure([go.Bar(x=trends.causes, y=[counter[cause] for cause in trends.causes], name=group)
                     for group, counter in groups.items()])
    fig.update_layout(barmode="stack", title=f"failure causes per {grouping}", height=320, margin=MARGIN,
                      yaxis_title="units failed")
    return fig
