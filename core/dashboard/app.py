"""The dashboard's web application: "the line now" live, the process of a part, a unit by its serial.

Read-only by construction: every route is a GET, the store is opened read-only
(:mod:`magline.core.dashboard.store`), and nothing on a page changes a limit, a station or a record.
Access as the station screen's: bound to loopback no login; bound to any other address every request
needs the token printed at start.
"""

from __future__ import annotations

import asyncio
import html
import json
import logging
import tempfile
import threading
import time
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from importlib.resources import files
from pathlib import Path
from typing import TYPE_CHECKING, Any

from fastapi import FastAPI, Request
from fastapi.responses import HTMLResponse, JSONResponse, PlainTextResponse, Response, StreamingResponse
from sse_starlette.sse import EventSourceResponse

from magline.core.dashboard.line import distinct, line_now, store_version
from magline.core.dashboard.wakeups import Wakeups
from magline.core.lazy import warm_imports
from magline.core.operator_ui.screen.app import TokenRequired, add_static_routes, versioned_plotly_src

if TYPE_CHECKING:
    from magline.core.dashboard.store import ReadOnlyStore
    from magline.core.quality.trends import Shifts

STATIC = files("magline.core.dashboard") / "static"
HEARTBEAT_S = 5.0
log = logging.getLogger("magline.dashboard")
PLOTLY_SRC = versioned_plotly_src()  # a browser keeps it: its code is compiled once, not at every page
WAKE_CHECK_S = 0.05  # how often an open page's stream looks whether the store was written
# What the chart and unit pages compute and draw with, imported when the dashboard starts
# (:func:`~magline.core.lazy.warm_imports`): the first visitor of a process page waited 0.6 s for SciPy's
# statistics and plotly's figure objects, a server that runs for weeks importing them on its first request
CHART_MODULES = ("scipy.stats", "plotly.graph_objects", "magline.core.quality.spc", "magline.core.reports.spc_page",
                 "magline.core.reports.page", "magline.core.results.series", "magline.core.results.control_limits",
                 "magline.core.dashboard.product", "magline.core.reports.unit_page")


def create_app(store: ReadOnlyStore, shifts: Shifts, token: str | None = None,
               now: Any = lambda: datetime.now(UTC)) -> FastAPI:
    warm_imports(*CHART_MODULES)
    app = FastAPI(title="magline dashboard", docs_url=None, redoc_url=None, openapi_url=None)
    app.state.closing = threading.Event()  # set by whoever stops a server run in a thread
    if token is not None:
        app.add_middleware(TokenRequired, token=token)
    wakeups = Wakeups(store)
    app.state.wakeups = wakeups  # closed by whoever serves the app (its listener connection)

    def line() -> dict[str, Any]:
        with store.engine.connect() as conn:
            return {**line_now(conn, now(), shifts), "store": store.where}

    @app.get("/", response_class=HTMLResponse)
    def page() -> HTMLResponse:
        return HTMLResponse((STATIC / "line.html").read_text(encoding="utf-8"))

    add_static_routes(app, STATIC)

    @app.get("/api/line")
    async def line_json() -> JSONResponse:
        return JSONResponse(await asyncio.to_thread(line))

    @app.get("/api/events")
    async def events(request: Request) -> EventSourceResponse:
        def version() -> tuple:
            with store.engine.connect() as conn:
                return store_version(conn)

        async def stream() -> Any:
            seen, quiet, woken = None, time.monotonic(), wakeups.count
            while not app.state.closing.is_set() and not await request.is_disconnected():
                current = await asyncio.to_thread(version)
                if current != seen:
                    seen, quiet = current, time.monotonic()
                    yield {"event": "line", "data": json.dumps(await asyncio.to_thread(line))}
                elif time.monotonic() - quiet >= HEARTBEAT_S:
                    quiet = time.monotonic()
                    yield {"event": "alive", "data": "{}"}
                # a notification, or the poll due — awaited on the event loop: a thread parked per open page
                # would exhaust the pool the queries run on once a few people watch the line
                due = time.monotonic() + wakeups.poll_s
                while wakeups.count == woken and time.monotonic() < due and not app.state.closing.is_set():
                    await asyncio.sleep(WAKE_CHECK_S)
                woken = wakeups.count
        return EventSourceResponse(stream())

    @app.get("/unit", response_class=HTMLResponse)
    async def unit(serial: str = "") -> HTMLResponse:
        return HTMLResponse(await asyncio.to_thread(_unit_page, store, serial))

    @app.get("/report/{run}", response_class=HTMLResponse)
    async def report(run: str) -> Response:
        text = await asyncio.to_thread(_report_page, store, run)
        return HTMLResponse(text) if text is not None else PlainTextResponse(f"no run {run!r}", status_code=404)

    @app.get("/process", response_class=HTMLResponse)
    async def process(request: Request) -> StreamingResponse:
        query = dict(request.query_params)
        return _chart_page("magline — the process", lambda: _process_page(store, query, shifts))

    @app.get("/product", response_class=HTMLResponse)
    async def product(part: str = "") -> StreamingResponse:
        return _chart_page("magline — design and supply", lambda: _product_page(store, part))

    return app


@dataclass(frozen=True)
class ChartPage:
    """A chart page as :func:`_chart_page` sends it after its head: its title and its body's HTML.
    ``framed``: the dashboard's own frame (a page with nothing to chart), which takes the dashboard's style."""

    title: str
    body: str
    framed: bool = False


def _chart_page(title: str, build: Callable[[], ChartPage]) -> StreamingResponse:
    """A page of charts, its head (with plotly.js) sent at once and the rest once ``build`` made it.  Why:
    the browser fetches and compiles plotly.js — a second on a first visit — while the server builds the
    figures (half a second), instead of after.  The page's own title follows in a line of script; a page
    without charts (nothing recorded yet) keeps the dashboard's style; a page that could not be built
    says why in one line."""

    async def parts() -> AsyncIterator[str]:
        from magline.core.reports.page import page_head

        yield page_head(title, PLOTLY_SRC)
        try:
            page = await asyncio.to_thread(build)
        except Exception as exc:  # the head is sent: the page says it, the log keeps the traceback
            log.exception("dashboard page %r", title)
            yield f"<body><p class=note>This page could not be built: {html.escape(str(exc))}</p></body></html>"
            return
        retitle = "<script>document.title = " + json.dumps(page.title).replace("</", "<\\/") + ";</script>"
        style = "<link rel=stylesheet href='/static/dashboard.css'>" if page.framed else ""
        yield f"<body>{retitle}{style}{page.body}</body></html>"

    return StreamingResponse(parts(), media_type="text/html; charset=utf-8")


def _product_page(store: ReadOnlyStore, part: str) -> ChartPage:
    """:mod:`magline.core.dashboard.product` for ``part`` (the latest recorded part when none is given)."""
    from sqlalchemy import func, select

    from magline.core.dashboard.product import product_figures, product_sections
    from magline.core.reports.page import page_body
    from magline.core.results.tables import runs

    with store.engine.connect() as conn:
        parts = [p for (p,) in conn.execute(select(runs.c.part).group_by(runs.c.part)
                                            .order_by(func.max(runs.c.id).desc())).all()]
        part = part or (parts[0] if parts else "")
        if not part:
            return ChartPage("magline — design and supply",
                             _frame_body("<h1>Design and supply</h1><p>No unit recorded yet.</p>"), framed=True)
        figures = product_figures(conn, part)
    choose = " ".join(f"<a href='/product?part={html.escape(p)}'>{html.escape(p)}</a>" for p in parts)
    nav = f"<nav class=process>parts: {choose} · <a href='/'>the line now</a></nav>"
    return ChartPage(f"magline — {part}", page_body([nav, *product_sections(part, figures)]))


FILTERS = (("station", "station"), ("line", "line"), ("operator", "operator"), ("compass", "compass (mag1, mag2 …)"),
           ("since", "since (ISO time)"), ("until", "until"), ("last", "latest runs"))


def _filters(query: dict[str, str], part: str) -> str:
    """The page's filters as a form whose answer is the page's address (a bookmark, a link in a mail)."""
    fields = "".join(f"<label>{html.escape(label)} <input name={name} value='{html.escape(query.get(name, ''))}'>"
                     "</label> " for name, label in FILTERS)
    shift = " checked" if query.get("shift") == "current" else ""
    return ("<form class=filters method=get action='/process'>"
            f"<input type=hidden name=part value='{html.escape(part)}'>{fields}"
            f"<label><input type=checkbox name=shift value=current{shift}> this shift</label> "
            "<button>show</button></form>")


def _compass_of(name: str) -> str:
    """``mag2.mounting_error_deg`` → mag2; an unprefixed measurement is the primary's, mag1."""
    head, dot, _ = name.partition(".")
    return head if dot and head.startswith("mag") and "-" not in head else "mag1"


def _frame(title: str, body: str) -> str:
    return (f"<!DOCTYPE html><html lang=en><head><meta charset=utf-8><title>{html.escape(title)}</title>"
            "<link rel=icon href='data:,'><link rel=stylesheet href='/static/dashboard.css'></head><body>"
            f"{_frame_body(body)}</body></html>")


def _frame_body(body: str) -> str:
    """The dashboard's navigation over ``body``: every page but a report's and a chart page's."""
    return ("<nav><a href='/'>the line now</a> · <a href='/process'>the process</a> · "
            "<a href='/product'>design and supply</a> · "
            "<form action='/unit' method=get class=search><input name=serial placeholder='serial' "
            "aria-label=serial><button>find</button></form></nav>"
            f"<main>{body}</main>")


def _unit_page(store: ReadOnlyStore, serial: str) -> str:
    """A unit's runs (any case of its serial, as ``magline history``), each linked to its report."""
    from sqlalchemy import select

    from magline.core.results.reading import same_serial
    from magline.core.results.tables import runs

    if not serial.strip():
        return _frame("magline — a unit", "<h1>A unit</h1><p>Type or scan a serial above.</p>")
    with store.engine.connect() as conn:
        found = conn.execute(select(runs.c.id, runs.c.serial, runs.c.part, runs.c.station_id, runs.c.started,
                                    runs.c.verdict, runs.c.cause)
                             .where(same_serial(conn, serial)).order_by(runs.c.id)).all()
    if not found:
        return _frame("magline — a unit", f"<h1>{html.escape(serial)}</h1><p class=note>No run of this serial in "
                      f"{html.escape(store.where)}.</p>")
    rows = "".join(f"<tr class='{html.escape(str(r.verdict))}'><td><a href='/report/{r.id}'>run {r.id}</a></td>"
                   f"<td>{html.escape(str(r.started))}</td><td>{html.escape(str(r.station_id))}</td>"
                   f"<td>{html.escape(str(r.part))}</td><td>{html.escape(str(r.verdict).upper())}</td>"
                   f"<td>{html.escape(r.cause or '')}</td></tr>" for r in found)
    return _frame(f"magline — {found[-1].serial}",
                  f"<h1>{html.escape(found[-1].serial)}</h1><p class=note>{len(found)} run(s), oldest first</p>"
                  "<table><tr><th>report</th><th>started</th><th>station</th><th>part</th><th>verdict</th>"
                  f"<th>cause</th></tr>{rows}</table>")


def _report_page(store: ReadOnlyStore, run: str) -> str | None:
    """The unit report ``magline report`` writes, plotly.js from this server."""
    from magline.core.reports.commands import stored_run
    from magline.core.reports.unit_page import write_unit_page

    with store.engine.connect() as conn:
        found = stored_run(conn, run)
    if found is None:
        return None
    with tempfile.TemporaryDirectory() as folder:
        return write_unit_page(found, Path(folder) / "unit.html", PLOTLY_SRC).read_text(encoding="utf-8")


def _process_page(store: ReadOnlyStore, query: dict[str, str], shifts: Shifts) -> ChartPage:
    """The control charts and capability ``magline spc`` computes for a part (its frozen limits where
    frozen), filtered as the address says; each point opens its unit's report."""
    from sqlalchemy import select

    from magline.core.quality.spc import build
    from magline.core.reports.page import page_body
    from magline.core.reports.spc_page import spc_sections
    from magline.core.results.control_limits import newest
    from magline.core.results.instants import stored_form
    from magline.core.results.reading import RunFilter
    from magline.core.results.series import load_series
    from magline.core.results.tables import runs

    station = query.get("station") or None
    with store.engine.connect() as conn:
        parts = distinct(conn, runs.c.part)
        at_station = conn.execute(select(runs.c.part).where(runs.c.station_id == station)
                                  .order_by(runs.c.started.desc()).limit(1)).scalar() if station else None
        latest = conn.execute(select(runs.c.part).order_by(runs.c.id.desc()).limit(1)).scalar()
        part = query.get("part") or at_station or latest
        if part is None:
            return ChartPage("magline — the process", _frame_body("<h1>The process</h1><p>No unit recorded yet.</p>"),
                             framed=True)
        since = query.get("since") or None
        if query.get("shift") == "current":  # the running shift, as the line's tiles count it
            since = stored_form(shifts.start_of(datetime.now(UTC)))
        where = RunFilter(part=part, station_id=station, line=query.get("line") or None,
                          operator=query.get("operator") or None, since=since, until=query.get("until") or None)
        last = int(query["last"]) if query.get("last", "").isdigit() else 500
        series = load_series(conn, where, last, None, True, True, None)
        frozen = newest(conn, part, where.station_id)
    choose = "".join(f"<a href='/process?part={html.escape(p)}'>{html.escape(p)}</a> " for p in parts)
    if not len(series):
        return ChartPage("magline — the process", _frame_body(
            f"<h1>The process</h1><p>parts: {choose}</p>"
            f"<p class=note>No runs of {html.escape(part)} match this filter.</p>"), framed=True)
    compass = query.get("compass") or None  # mag1 (the primary), mag2 …: that compass's characteristics only
    names = None if compass is None else [n for n in series.values if _compass_of(n) == compass]
    title = f"part {part}" + (f", station {station}" if station else ", every station") + "".join(
        f", {word} {value}" for word, value in (("line", where.line), ("operator", where.operator),
                                                ("compass", compass)) if value) + f", latest {len(series)} runs"
    report = build(series, title, names, 50, frozen=frozen, shifts=shifts)
    links = {int(r["id"]): f"/report/{r['id']}" for r in series.runs}
    title, sections = spc_sections(report, links)
    signals = "".join(f"<li><a href='/report/{series.runs[m.chart.index[s.point]]['id']}'>"
                      f"{html.escape(str(series.runs[m.chart.index[s.point]]['serial']))}</a>: {html.escape(m.name)},"
                      f" rule {html.escape(s.rule)}</li>" for m in report.measurements for s in m.chart.signals)
    nav = (f"<nav class=process>parts: {choose} · <a href='/'>the line now</a></nav>" + _filters(query, part)
           + (f"<h2>Signals</h2><ul class=signals>{signals}</ul>" if signals else ""))
    return ChartPage(title, nav + page_body(sections))
