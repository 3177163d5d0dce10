"""Headless Chromium from Debian's ``chromium`` package, driven by python playwright (never a
downloaded browser).  Every page records the requests it makes, so a test can prove a report asks
nothing of the network."""

from __future__ import annotations

import base64
import re
import shutil
import socket
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import uvicorn

# What keeps Chromium from phoning home at start (its own update, sync and field-trial requests),
# so that the requests a test sees are the page's.
FLAGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
         "--disable-sync", "--no-first-run", "--disable-quic", "--disable-default-apps",
         # Source positions kept at compile time.  Why: a page driven by playwright has the DevTools protocol's
         # runtime on, which records where each console message and exception was raised; V8 works that out by
         # parsing the script again, and for plotly.js (4.8 MB, one function at its top) that was a second of
         # each page's load that a browser nobody drives never spends (1.8 s of plotly.js here without the
         # protocol, 2.4 s with it, 1.4 s with this flag).  No page behaves otherwise for it.
         "--js-flags=--no-enable-lazy-source-positions"]


# Chromium features the tests' browser turns off beside playwright's own.  Why: Chromium 156 renders its
# omnibox popups as WebUI pages (``chrome://omnibox-popup.top-chrome``) and starts one in a renderer of its own
# for every new window, which each playwright context is: measured here, 0.3 s of CPU for an empty page and
# 1.5 s for one that loads plotly.js (3.5 s → 2.0 s), a headless browser never showing either popup.
QUIET_FEATURES = ("WebUIOmniboxPopup", "WebUIOmniboxAimPopup")


def playwright_disabled_features() -> list[str]:
    """The features playwright's driver itself disables in Chromium (``chromiumSwitches``), read from the
    installed driver.  Why: Chromium keeps only the last ``--disable-features`` it is given, so a list of
    our own must repeat playwright's.  Empty when the driver no longer says them where this looks."""
    import playwright

    driver = Path(playwright.__file__).parent / "driver" / "package" / "lib"
    for source in (driver / "coreBundle.js", driver / "server" / "chromium" / "chromiumSwitches.js"):
        if source.is_file():
            found = re.search(r"disabledFeatures = \[(.*?)\]", source.read_text(encoding="utf-8"), re.DOTALL)
            if found:
                return re.findall(r'"(\w+)"', re.sub(r"//[^\n]*", "", found.group(1)))
    return []


def launch_flags() -> list[str]:
    """:data:`FLAGS`, and the features to turn off: playwright's and :data:`QUIET_FEATURES`.  Where
    playwright's own list cannot be read, its switch is left alone (the browser then costs more, and
    behaves as playwright means it to)."""
    theirs = playwright_disabled_features()
    return FLAGS + ([f"--disable-features={','.join(theirs + list(QUIET_FEATURES))}"] if theirs else [])


# How long a test waits for what a page must show (its load, its charts drawn, a verdict, a tile updated): a
# guard against a page that never shows it, not a speed limit.  A report embeds plotly.js: a quiet machine
# loads it in a second, one at load 8 in tens of seconds, and both are right; playwright's own 30 s made the
# second a failure.  No assertion depends on how soon; the benchmarks measure that.
EVENT_WAIT_MS = 300_000


def chromium_path() -> str:
    path = shutil.which("chromium")
    if path is None:
        raise RuntimeError("Debian's chromium is not installed: run the README's test command, which installs it")
    return path


@contextmanager
def chromium() -> Any:
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium_path(), args=launch_flags())
        try:
            yield browser
        finally:
            browser.close()


@dataclass
class Opened:
    page: Any
    requests: list[str] = field(default_factory=list)
    console: list[str] = field(default_factory=list)  # every console message and page error, as text

    def outside(self, allowed: tuple[str, ...]) -> list[str]:
        return [u for u in self.requests if not u.startswith(allowed)]


def new_page(browser: Any, viewport: tuple[int, int] = (1300, 900)) -> Any:
    """A page in a context of its own that waits for events as long as :data:`EVENT_WAIT_MS`."""
    page = browser.new_page(viewport={"width": viewport[0], "height": viewport[1]})
    page.set_default_timeout(EVENT_WAIT_MS)
    return page


def open_page(browser: Any, url: str, viewport: tuple[int, int] = (1300, 900)) -> Opened:
    page = new_page(browser, viewport)
    opened = Opened(page)
    page.on("request", lambda request: opened.requests.append(request.url))
    page.on("console", lambda message: opened.console.append(f"{message.type}: {message.text}"))
    page.on("pageerror", lambda error: opened.console.append(f"error: {error}"))
    page.goto(url)
    return opened


def plots_with_data(page: Any) -> dict[str, int]:
    """Every plotly chart on the page, once all are drawn (a page draws them one after another, those in
    view first): its div id → how many data points its traces hold, as plotly.js itself decoded them
    (``_fullData``: the figure's arrays travel base64-encoded)."""
    page.wait_for_function("document.querySelectorAll('.js-plotly-plot').length > 0 && "
                           "!document.querySelector('.plot-pending') && "
                           "[...document.querySelectorAll('.js-plotly-plot')].every(e => e._fullData)")
    return page.evaluate("""() => Object.fromEntries([...document.querySelectorAll('.js-plotly-plot')].map(
        e => [e.id, e._fullData.reduce((n, t) => n + ((t.x || t.z || []).length || 0), 0)]))""")


def drawn_points(page: Any) -> dict[str, int]:
    """Every chart's markers as the browser drew them (SVG paths of plotly's scatter layer), by div id:
    what a person sees, not the data the page carries."""
    return page.evaluate("""() => Object.fromEntries([...document.querySelectorAll('.js-plotly-plot')].map(
        e => [e.id, e.querySelectorAll('.scatterlayer .point').length]))""")


def colour_pixels(page: Any, selector: str, colours: dict[str, str], within: int = 40,
                  path: Path | None = None) -> dict[str, int]:
    """How many pixels of the element's screenshot lie within ``within`` (per channel) of each colour
    (``#rrggbb``), the PNG decoded by the browser itself: what a person sees, not what the page carries."""
    shot = base64.b64encode(page.locator(selector).screenshot(path=None if path is None else str(path))).decode()
    wanted = {name: [int(c[i:i + 2], 16) for i in (1, 3, 5)] for name, c in colours.items()}
    return page.evaluate("""async ([png, wanted, within]) => {
        const img = new Image(); img.src = "data:image/png;base64," + png; await img.decode();
        const c = document.createElement("canvas"); c.width = img.width; c.height = img.height;
        const g = c.getContext("2d"); g.drawImage(img, 0, 0); const d = g.getImageData(0, 0, c.width, c.height).data;
        const out = Object.fromEntries(Object.keys(wanted).map(k => [k, 0]));
        for (let i = 0; i < d.length; i += 4)
            for (const [k, [r, gr, b]] of Object.entries(wanted))
                if (Math.abs(d[i] - r) < within && Math.abs(d[i + 1] - gr) < within && Math.abs(d[i + 2] - b) < within)
                    out[k] += 1;
        return out; }""", [shot, wanted, within])


def screenshot(page: Any, path: Path) -> Path:
    page.screenshot(path=str(path), full_page=True)
    return path


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Served:
    """The app on a real socket, in a thread; stoppable and startable again on the same port."""

    def __init__(self, app, port: int) -> None:
        self.app, self.port = app, port
        self.start()

    def start(self) -> None:
        self.app.state.closing.clear()
        config = uvicorn.Config(self.app, host="127.0.0.1", port=self.port, log_level="warning",
                                timeout_graceful_shutdown=1)
        self.server = uvicorn.Server(config)
        self.thread = threading.Thread(target=self.server.run, daemon=True)
        self.thread.start()
        deadline = time.monotonic() + 20
        while not self.server.started:
            assert time.monotonic() < deadline, "the screen did not start"
            time.sleep(0.05)

    def stop(self) -> None:
        self.app.state.closing.set()
        self.server.should_exit = True
        self.thread.join(timeout=20)

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}/"
