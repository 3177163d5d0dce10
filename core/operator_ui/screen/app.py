"""The station screen's web application: the page, its live state (server-sent events), start and
abort, the unit reports, and plotly.js from the installed plotly package (a line PC has no
internet, so nothing comes from a CDN).

Access: bound to 127.0.0.1 the screen is the line PC's own and needs no login.  Bound to any other
address, every request needs the operator token generated at start (``?token=`` once in the
address, then a cookie; or ``Authorization: Bearer``): a station that writes calibrations into
flight controllers must not be startable or abortable by anyone on the factory network.
"""

from __future__ import annotations

import asyncio
import hmac
import json
import threading
from importlib.resources import files
from pathlib import Path
from typing import Any

from fastapi import FastAPI, Request
from fastapi.responses import FileResponse, HTMLResponse, JSONResponse, PlainTextResponse, Response
from sse_starlette.sse import EventSourceResponse

from magline.core.operator_ui.screen.runner import Busy, UnitRunner
from magline.core.operator_ui.screen.state import ScreenState, bin_centres

STATIC = files("magline.core.operator_ui.screen") / "static"
COOKIE = "magline_token"
HEARTBEAT_S = 5.0  # an idle stream still says it is alive, so the page notices a dead server
WAIT_S = 0.5


def plotly_js_path() -> Path:
    import plotly

    return Path(plotly.__file__).parent / "package_data" / "plotly.min.js"


def versioned_plotly_src() -> str:
    """The address of plotly.js named by the installed plotly's version (``/static/plotly-VERSION.min.js``):
    a browser may keep it for good — the script and the code its engine compiled from it — because another
    plotly answers at another address.  Why: compiling 4.8 MB of script took nearly a second of every chart
    page's time on a two-core PC, each time it was opened."""
    from importlib.metadata import version

    return f"/static/plotly-{version('plotly')}.min.js"


def add_static_routes(app: FastAPI, folder: Any) -> None:
    """``/static/plotly.min.js`` from the installed plotly package (and at its versioned address, kept by
    the browser for a year) and ``/static/NAME`` from ``folder`` (a page's own scripts and styles): the
    pages ask nothing of the internet."""

    @app.get("/static/plotly.min.js")
    def plotly_js() -> FileResponse:
        return FileResponse(plotly_js_path(), media_type="text/javascript")

    @app.get(versioned_plotly_src())
    def plotly_js_versioned() -> FileResponse:
        return FileResponse(plotly_js_path(), media_type="text/javascript",
                            headers={"Cache-Control": "public, max-age=31536000, immutable"})

    @app.get("/static/{name}")
    def static(name: str) -> Response:
        item = folder / name
        if "/" in name or not item.is_file():
            return PlainTextResponse("not found", status_code=404)
        kind = {"js": "text/javascript", "css": "text/css"}.get(name.rsplit(".", 1)[-1], "text/plain")
        return Response(item.read_bytes(), media_type=kind)


class TokenRequired:
    """Plain ASGI middleware (it must not buffer the event stream): 401 without the token; a token
    given in the address is kept in a cookie so the page's own requests carry it."""

    def __init__(self, app: Any, token: str) -> None:
        self.app, self.token = app, token

    async def __call__(self, scope: dict, receive: Any, send: Any) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        request = Request(scope)
        in_address = request.query_params.get("token")
        given = (in_address or request.cookies.get(COOKIE)
                 or request.headers.get("authorization", "").removeprefix("Bearer ").strip())
        if not given or not hmac.compare_digest(given.encode(), self.token.encode()):
            refused = PlainTextResponse("operator token required (printed when the station started)", status_code=401)
            await refused(scope, receive, send)
            return

        async def send_with_cookie(message: dict) -> None:
            if message["type"] == "http.response.start" and in_address:
                cookie = f"{COOKIE}={self.token}; HttpOnly; SameSite=Strict; Path=/".encode()
                message["headers"] = [*message.get("headers", []), (b"set-cookie", cookie)]
            await send(message)

        await self.app(scope, receive, send_with_cookie)


def create_app(state: ScreenState, runner: UnitRunner, token: str | None = None,
               reports: Path | None = None) -> FastAPI:
    app = FastAPI(title="magline station", docs_url=None, redoc_url=None, openapi_url=None)
    # Set by whoever stops a server it runs in a thread (no signal handler for sse-starlette to
    # watch there): open event streams end within WAIT_S instead of holding up the shutdown.
    app.state.closing = threading.Event()

    if token is not None:
        app.add_middleware(TokenRequired, token=token)

    @app.get("/", response_class=HTMLResponse)
    def page() -> HTMLResponse:
        return HTMLResponse((STATIC / "index.html").read_text(encoding="utf-8"))

    add_static_routes(app, STATIC)

    @app.get("/api/state")
    def current() -> JSONResponse:
        return JSONResponse(state.snapshot()[1])

    @app.get("/api/bins/{n_bins}")
    def centres(n_bins: int) -> JSONResponse:
        if not 1 <= n_bins <= 10_000:
            return JSONResponse({"error": "bin count out of range"}, status_code=400)
        return JSONResponse(bin_centres(n_bins), headers={"Cache-Control": "max-age=86400"})

    @app.get("/api/events")
    async def events(request: Request) -> EventSourceResponse:
        async def stream() -> Any:
            version, quiet = -1, 0.0
            while not app.state.closing.is_set() and not await request.is_disconnected():
                # short waits: a shutting-down server is not held up by a thread parked in a long one
                newer = await asyncio.to_thread(state.wait_newer, version, WAIT_S)
                if newer or version < 0:
                    version, snapshot = state.snapshot()
                    quiet = 0.0
                    yield {"event": "state", "data": json.dumps(snapshot)}
                elif (quiet := quiet + WAIT_S) >= HEARTBEAT_S:
                    quiet = 0.0
                    yield {"event": "alive", "data": "{}"}
        return EventSourceResponse(stream())

    @app.post("/api/start")
    async def start(request: Request) -> JSONResponse:
        body = await request.json()
        try:  # on a worker thread: a start may wait for the last unit's wind-down
            if isinstance(body.get("serials"), dict):  # a load of a slot station
                await asyncio.to_thread(runner.start_slots, {str(k): str(v) for k, v in body["serials"].items()},
                                        str(body.get("operator", "")))
            else:
                await asyncio.to_thread(runner.start, str(body.get("serial", "")), body.get("part") or None,
                                        str(body.get("operator", "")))
        except Busy as exc:
            return JSONResponse({"error": str(exc)}, status_code=409)
        except ValueError as exc:  # the slot a refused load's label is to be scanned again for, where named
            if not state.testing():  # the last unit's verdict is old news: under the refusal it read as this label's
                state.forget_result()
            return JSONResponse({"error": str(exc), "slot": getattr(exc, "slot", None)}, status_code=400)
        return JSONResponse({"started": body.get("serial")})

    @app.post("/api/abort")
    def abort() -> JSONResponse:
        return JSONResponse({"aborting": runner.abort()})

    @app.post("/api/answer")
    async def answer(request: Request) -> JSONResponse:
        """The operator's yes or no to the question on the screen (the propellers off before a motor test)."""
        body = await request.json()
        try:
            question = int(body.get("id"))
        except (TypeError, ValueError):
            return JSONResponse({"error": "answer: which question (id) is missing"}, status_code=400)
        if not state.answer(question, body.get("yes") is True):
            return JSONResponse({"error": "that question is no longer asked"}, status_code=409)
        return JSONResponse({"answered": question})

    @app.get("/reports/{name}")
    def report(name: str) -> Response:
        path = (reports / name) if reports is not None and "/" not in name else None
        if path is None or not path.is_file():
            return PlainTextResponse("no such report", status_code=404)
        return FileResponse(path, media_type="text/html")

    return app
