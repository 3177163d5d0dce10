"""``magline dashboard`` in Debian's Chromium: tiles that follow a real ``magline run``, a process signal
that opens its unit, the token off loopback, an empty store, a store it cannot open — and a store it never
writes."""

from __future__ import annotations

import hashlib
import re
import subprocess
import sys
import urllib.error
import urllib.request
from datetime import datetime, time

import numpy as np
import pytest
from browser import EVENT_WAIT_MS, Served, free_port, open_page, screenshot
from simstation import FAST_SENSOR_HZ, write_station

from magline.core.dashboard.app import create_app
from magline.core.dashboard.store import open_read_only
from magline.core.measurements import Numeric, Verdict
from magline.core.quality.trends import Shifts
from magline.core.record import Outcome, RunRecord, now_iso
from magline.core.results.sqlite_store import SqliteSink
from magline.sim import create_sim

LOCAL = ("http://127.0.0.1:",)


def magline(*args: str, cwd=None, timeout: float = 120.0) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "magline.core.cli", *args], cwd=cwd, capture_output=True, text=True,
                          timeout=timeout)


def unit(serial: str, measurements: list, part: str = "P-1", station_id: str = "st-a", line: str = "L1",
         operator: str = "ann", unit_info: dict | None = None) -> RunRecord:
    record = RunRecord(serial=serial, part=part, station_id=station_id, line=line, operator=operator,
                       software_version="test", limit_hash="x")
    record.measurements, record.verdict, record.unit_info = measurements, Outcome.PASS, unit_info or {}
    return record


def write_units(path, records: list[RunRecord]) -> None:
    """Units written to a SQLite store as a station records them (begun, then finished with an end time)."""
    sink = SqliteSink(path)
    try:
        for record in records:
            sink.begin(record)
            record.finished = now_iso()
            sink.finish(record)
    finally:
        sink.close()


def recorded(path, serials_values, station_id="st-a", line="L1"):
    """Units of part P-1 with the hard-iron norms given."""
    write_units(path, [unit(serial, [Numeric("hard_iron_norm_ut", value, "µT", None, 300.0, Verdict.PASS)],
                            station_id=station_id, line=line) for serial, value in serials_values])


def shift_far_from_now() -> Shifts:
    """One shift a day, starting twelve hours from now (local clock): the tests count the running shift's
    units with the real clock, and a day's boundary met between two of their units (a run across midnight)
    had them wait for a count that never came."""
    return Shifts((time((datetime.now().hour + 12) % 24, 0),))


@pytest.fixture
def dashboard():
    started = []

    def start(target, token=None):
        store = open_read_only(str(target))
        served = Served(create_app(store, shift_far_from_now(), token), free_port())
        started.append((served, store))
        return served

    yield start
    for served, store in started:
        served.stop()
        served.app.state.wakeups.close()
        store.close()


def test_a_tile_follows_a_unit_recorded_by_a_real_magline_run_without_a_reload(dashboard, browser, tmp_path):
    """A simulated PX4 calibrated by ``magline run``: the station's tile counts it, lists its serial first and
    its first-pass yield, and the page was never reloaded; the store's bytes are as the station left them."""
    with create_sim("px4", "udp:127.0.0.1:0", mag_rate_hz=FAST_SENSOR_HZ, workdir=tmp_path / "fc", seed=5,
                    boot_time_s=0.3, speed=5.0) as sim:
        station = write_station("px4-sim.yaml", tmp_path, sim.address.replace("udp:", "udpout://"),
                                {"connect_timeout_s": 5.0, "boot_timeout_s": 10.0})
        first = magline("run", str(station), "--serial", "DASH-1")
        assert first.returncode == 0, first.stderr[-2000:]
        served = dashboard(tmp_path / "results.sqlite")
        opened = open_page(browser, served.url)
        page = opened.page
        page.wait_for_selector(".tile[data-station='sim-px4-01'] .units:has-text('1 unit this shift')")
        drawn = page.evaluate("window.__shown")
        second = magline("run", str(station), "--serial", "DASH-2")
        assert second.returncode == 0, second.stderr[-2000:]
        page.wait_for_selector(".tile[data-station='sim-px4-01'] .units:has-text('2 units this shift')")
    assert page.evaluate("window.__shown") > drawn and page.evaluate("performance.navigation.type") == 0  # no reload
    tile = page.inner_text(".tile[data-station='sim-px4-01']")
    assert tile.splitlines()[0].startswith("sim-px4-01") and "first-pass yield 100%" in tile
    assert [e.strip() for e in page.eval_on_selector_all(".tile .recent li a", "els => els.map(e => e.textContent)")] \
        == ["DASH-2", "DASH-1"]
    page.click(".tile .recent li a >> nth=0")  # a unit: its runs, each opening the report `magline report` writes
    page.wait_for_selector("h1:has-text('DASH-2')")
    page.click("a:has-text('run 2')")
    page.wait_for_selector("text=DASH-2")
    assert "MOCK" not in page.title() and page.url.endswith("/report/2")
    screenshot(page, tmp_path / "dashboard-unit-report.png")
    assert opened.outside(LOCAL) == []


def test_a_process_signal_links_to_the_unit_behind_it(dashboard, browser, tmp_path):
    """The process page is ``spc``'s (its charts and rules): a step in a part's offsets signals, and the
    signal opens the report of the unit that completed it; the filters are in the address."""
    rng = np.random.default_rng(7)
    values = [(f"U-{i}", rng.normal(74.0, 0.5) + (3.0 if i >= 60 else 0.0)) for i in range(70)]
    recorded(tmp_path / "line.sqlite", values)
    served = dashboard(tmp_path / "line.sqlite")
    opened = open_page(browser, served.url + "process?part=P-1&station=st-a")
    page = opened.page
    page.wait_for_selector("ul.signals li a")
    signals = page.eval_on_selector_all("ul.signals li a", "els => els.map(a => ({text: a.textContent, "
                                        "href: a.getAttribute('href')}))")
    step = [s for s in signals if int(s["text"].split("-")[1]) >= 60]  # the units of the step signal
    assert step and all(s["href"].startswith("/report/") for s in signals)
    first = step[0]
    assert "station st-a" in page.inner_text("h1")
    page.click(f"ul.signals li a[href='{first['href']}'] >> nth=0")
    page.wait_for_selector(f"text={first['text']}")
    assert page.url.endswith(first["href"])
    assert opened.outside(LOCAL) == []


def test_a_page_over_an_empty_store_says_what_to_do_first(dashboard, browser, tmp_path):
    SqliteSink(tmp_path / "empty.sqlite").close()  # a station's store before its first unit
    page = open_page(browser, dashboard(tmp_path / "empty.sqlite").url).page
    page.wait_for_selector("#empty:not([hidden])")
    assert "magline run" in page.inner_text("#empty") and page.inner_text("#tiles") == ""


def test_off_loopback_every_request_needs_the_token_and_the_store_is_never_written(tmp_path):
    """Bound to another address the dashboard prints its token once; without it nothing is served. The
    SQLite file is opened read-only: its bytes after the pages were served are the bytes before."""
    recorded(tmp_path / "line.sqlite", [("T-1", 74.0), ("T-2", 74.2)])
    before = hashlib.sha256((tmp_path / "line.sqlite").read_bytes()).hexdigest()
    port = free_port()
    proc = subprocess.Popen([sys.executable, "-m", "magline.core.cli", "dashboard", "--store",
                             str(tmp_path / "line.sqlite"), "--host", "0.0.0.0", "--port", str(port)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        said = proc.stdout.readline()
        assert "token=" in said and "(token shown once)" in said, said
        token = said.split("token=")[1].split()[0]
        with pytest.raises(urllib.error.HTTPError) as refused:
            urllib.request.urlopen(f"http://127.0.0.1:{port}/api/line", timeout=10)
        assert refused.value.code == 401
        for path in ("api/line", "unit?serial=t-1", "process", "report/1"):
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/{path}{'&' if '?' in path else '?'}token={token}",
                                        timeout=30) as answer:
                assert answer.status == 200, path
    finally:
        proc.terminate()
        proc.wait(10)
    assert hashlib.sha256((tmp_path / "line.sqlite").read_bytes()).hexdigest() == before


def test_port_zero_serves_on_a_port_the_system_chose_and_announces_that_one(tmp_path):
    recorded(tmp_path / "line.sqlite", [("T-1", 74.0)])
    proc = subprocess.Popen([sys.executable, "-m", "magline.core.cli", "dashboard", "--store",
                             str(tmp_path / "line.sqlite"), "--port", "0"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        said = proc.stdout.readline()
        port = int(said.rstrip().rstrip("/").rsplit(":", 1)[1])
        assert port != 0, said
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/line", timeout=30) as answer:
            assert answer.status == 200 and "T-1" in answer.read().decode()
    finally:
        proc.terminate()
        proc.wait(10)


@pytest.mark.parametrize("kind", ["missing", "not-magline", "server-refused"])
def test_a_store_the_dashboard_cannot_open_is_one_clear_line(tmp_path, kind):
    from dead_ports import refused_port

    if kind == "missing":
        target = str(tmp_path / "nowhere.sqlite")
    elif kind == "not-magline":
        import sqlite3

        with sqlite3.connect(tmp_path / "other.sqlite") as conn:
            conn.execute("CREATE TABLE t (x)")
        target = str(tmp_path / "other.sqlite")
    with refused_port() as port:
        if kind == "server-refused":
            target = f"postgresql+psycopg://reader:secret@127.0.0.1:{port}/magline"
        done = magline("dashboard", "--store", target, "--port", str(free_port()), timeout=60)
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1 and lines[0].startswith("magline dashboard: results store"), \
        done.stderr
    assert "secret" not in done.stderr and "Traceback" not in done.stderr


def test_a_store_at_another_schema_version_is_one_line_saying_how_it_is_brought_up_to_date(tmp_path):
    """Read-only, the dashboard cannot migrate a store: one written by an older magline is named, not read
    half-way into a page that fails on a missing column."""
    import sqlite3

    from magline.core.faults import StationFault

    recorded(tmp_path / "old.sqlite", [("OLD-1", 74.0)])
    with sqlite3.connect(tmp_path / "old.sqlite") as conn:
        conn.execute("UPDATE alembic_version SET version_num = '0016'")
    with pytest.raises(StationFault, match=r"schema 0016, this magline reads \d{4} — a station of this version"):
        open_read_only(str(tmp_path / "old.sqlite"))


def test_a_product_page_shows_each_compass_s_distribution_and_the_firmware_its_units_ran(dashboard, browser,
                                                                                         tmp_path):
    """Per product, where a design or supplier change shows: each compass's mounting error (a trace per
    compass: the mast's and the board's never pooled), and the firmware versions the units ran."""
    rng = np.random.default_rng(3)
    write_units(tmp_path / "line.sqlite", [
        unit(f"F-{i}", [Numeric("mounting_error_deg", abs(rng.normal(0.3, 0.1)), "°", None, 3.0, Verdict.PASS),
                        Numeric("mag2.mounting_error_deg", abs(rng.normal(1.2, 0.2)), "°", None, 3.0, Verdict.PASS)],
             part="P-2", station_id="st-b", operator="bo", unit_info={"firmware": "1.15.0" if i < 30 else "1.16.0"})
        for i in range(40)])
    opened = open_page(browser, dashboard(tmp_path / "line.sqlite").url + "product?part=P-2")
    page = opened.page
    page.wait_for_function("document.getElementById('hist-mounting_error_deg') && "
                           "document.getElementById('hist-mounting_error_deg').data")
    traces = page.evaluate("document.getElementById('hist-mounting_error_deg').data.map(t => t.name)")
    assert traces == ["mag1 (40)", "mag2 (40)"]
    # each compass's 40 values, as plotly.js decoded them from the page (packed as typed arrays)
    decoded = page.evaluate("document.getElementById('hist-mounting_error_deg')._fullData.map(t => t.x.length)")
    assert decoded == [40, 40]
    rows = page.eval_on_selector_all("table tbody tr", "rows => rows.map(r => r.innerText.split('\\t').slice(0, 2))")
    assert rows == [["1.15.0", "30"], ["1.16.0", "10"]]
    assert "not measured on this product" in page.inner_text("body")  # no interference sweep on this part
    assert opened.outside(LOCAL) == []


def test_on_postgresql_a_recorded_unit_wakes_the_page_by_notification(dashboard, browser, postgres, monkeypatch):
    """A line's PostgreSQL store: its writers NOTIFY at commit and the dashboard LISTENs, so a unit recorded
    by any station reaches the tile at once — here with the page's own poll set to a minute, so nothing but
    the notification can bring it. The dashboard's sessions are read-only whatever its role may do."""
    from sqlalchemy import create_engine, text
    from sqlalchemy.exc import InternalError, ProgrammingError

    from magline.core.dashboard import wakeups
    from magline.core.results.store import SqlStore

    monkeypatch.setattr(wakeups, "POLL_NOTIFIED_S", 60.0)
    url = postgres.new_database()
    writer = SqlStore(create_engine(url), "line server")

    def record(serial: str) -> None:
        unit = RunRecord(serial=serial, part="P-9", station_id="st-pg", line="L9", operator="ann",
                         software_version="test", limit_hash="x")
        unit.verdict = Outcome.PASS
        writer.begin(unit)
        writer.finish(unit)

    try:
        record("PG-1")
        served = dashboard(url)
        page = open_page(browser, served.url).page
        page.wait_for_selector(".tile[data-station='st-pg'] .units:has-text('1 unit this shift')")
        record("PG-2")
        page.wait_for_selector(".tile[data-station='st-pg'] .units:has-text('2 units this shift')")
        store = open_read_only(url)
        try:
            with store.engine.connect() as conn, pytest.raises((InternalError, ProgrammingError)):
                conn.execute(text("DELETE FROM runs"))  # refused: a read-only transaction
        finally:
            store.close()
    finally:
        writer.close()


def test_many_open_pages_do_not_starve_the_dashboard(dashboard, browser, tmp_path):
    """Twelve people watching the line (twelve open event streams, more than the server's worker threads on
    two cores): a unit page still answers, and every page follows a new unit."""
    recorded(tmp_path / "line.sqlite", [("W-1", 74.0)])
    served = dashboard(tmp_path / "line.sqlite")
    contexts = [browser.new_context() for _ in range(12)]  # twelve viewers (a browser holds 6 connections a host)
    try:
        pages = [context.new_page() for context in contexts]
        for page in pages:
            page.set_default_timeout(EVENT_WAIT_MS)
        for page in pages:
            page.goto(served.url)
            page.wait_for_selector(".tile .units:has-text('1 unit this shift')")
        with urllib.request.urlopen(served.url + "unit?serial=w-1", timeout=30) as answer:
            assert answer.status == 200 and "W-1" in answer.read().decode()
        recorded(tmp_path / "line.sqlite", [("W-2", 74.1)])
        for page in pages:
            try:
                page.wait_for_selector(".tile .units:has-text('2 units this shift')")
            except Exception:
                shown = [p.evaluate("[document.querySelector('.tile .units') && document.querySelector('.tile "
                                    ".units').textContent, window.__shown, !document.getElementById('banner')"
                                    ".hidden]") for p in pages]
                raise AssertionError(f"pages: {shown}") from None
    finally:
        for context in contexts:
            context.close()


def test_the_process_page_filters_by_operator_and_compass_and_its_address_holds_them(dashboard, browser, tmp_path):
    """Two operators' units of a two-compass product: ``operator=bo&compass=mag2`` charts only bo's runs and
    only the second compass's characteristics; the filters are in the address and in the form that made it;
    a station's tile opens the process of the part that station tests."""
    rng = np.random.default_rng(9)
    write_units(tmp_path / "line.sqlite", [
        unit(f"C-{i}", [Numeric("hard_iron_norm_ut", rng.normal(74.0, 0.5), "µT", None, 300.0, Verdict.PASS),
                        Numeric("mag2.hard_iron_norm_ut", rng.normal(30.0, 0.5), "µT", None, 300.0, Verdict.PASS)],
             part="P-3", station_id="st-c", operator="ann" if i % 3 else "bo") for i in range(30)])
    recorded(tmp_path / "line.sqlite", [("OTHER-1", 74.0)], station_id="st-z")  # another part, recorded last
    served = dashboard(tmp_path / "line.sqlite")
    page = open_page(browser, served.url + "process?station=st-c&operator=bo&compass=mag2").page
    page.wait_for_selector("h1")
    title = page.inner_text("h1")
    assert "part P-3, station st-c, operator bo, compass mag2, latest 10 runs" in title, title
    charts = page.eval_on_selector_all(".imr-chart .plotly-graph-div", "els => els.map(e => e.id)")
    assert charts == ["chart-mag2.hard_iron_norm_ut"]
    assert page.input_value("form.filters input[name=operator]") == "bo"
    page.fill("form.filters input[name=operator]", "ann")
    page.click("form.filters button")
    page.wait_for_selector("h1:has-text('operator ann')")
    assert "operator=ann" in page.url and "compass=mag2" in page.url and "latest 20 runs" in page.inner_text("h1")


def test_a_station_with_slots_has_a_tile_per_slot_saying_what_each_tests_now(dashboard, browser, tmp_path):
    """Four units on one gimbal are four fixture positions: a tile each, its own units and yield, and the
    serial its slot claim says is under test there now (a claim the computer keeps refreshing)."""
    from datetime import UTC

    from sqlalchemy import create_engine, insert

    from magline.core.results.tables import slot_claims

    records = []
    for i in range(6):
        record = unit(f"S-{i}", [], station_id="st-s", line="L2")
        record.slot = "A" if i % 2 else "B"
        records.append(record)
    write_units(tmp_path / "line.sqlite", records)
    engine = create_engine(f"sqlite:///{tmp_path / 'line.sqlite'}")
    now = datetime.now(UTC).isoformat(timespec="milliseconds")
    with engine.begin() as conn:
        conn.execute(insert(slot_claims).values(station_id="st-s", slot="A", host="pc", pid=1, serial="S-NOW",
                                                since=now, heartbeat=now))
    engine.dispose()
    page = open_page(browser, dashboard(tmp_path / "line.sqlite").url).page
    page.wait_for_selector(".tile[data-slot='B']")
    a, b = page.inner_text(".tile[data-slot='A']"), page.inner_text(".tile[data-slot='B']")
    assert a.startswith("st-s · slot A") and "testing S-NOW" in a and "3 units this shift" in a
    assert b.startswith("st-s · slot B") and "no unit under test" in b and "3 units this shift" in b


def test_a_forwarding_station_s_tile_says_what_its_outbox_holds_and_when_its_field_was_checked(
        dashboard, browser, postgres, make_station, monkeypatch, tmp_path):
    """A station forwarding to the line's PostgreSQL through its outbox, its field checked by a fluxgate before
    every unit: the tile shows the last check (value, time, units) and what the outbox held when the station
    last reached the server — empty after a good pass; one record queued when the server refused a run — and
    the page follows the report without a reload."""
    from magline.core.plugins import load_plugins
    from magline.core.results import forwarding
    from magline.core.sequencer import Sequencer
    from magline.core.station import load_station
    from magline.sim.fluxgate import FluxgateSim

    url = postgres.new_database()
    monkeypatch.setenv("MAGLINE_LINE_URL", url)
    with FluxgateSim("tcp:127.0.0.1:0", lambda: np.array([0.0, 0.0, 48.02]), noise_ut=0.0) as fluxgate:
        path = make_station({"results": {"sink": "sql", "url_env": "MAGLINE_LINE_URL", "outbox": "outbox.sqlite"},
                             "field_source": {"type": "fixed", "options": {
                                 "field_ut": 48.0, "inclination_deg": 63.0,
                                 "reference": {"resource": fluxgate.visa_resource, "readings": 2,
                                               "every_n_units": 1}}}})
        seq = Sequencer(load_station(path), load_plugins(), path.parent, sleep=lambda s: None)
        try:
            assert seq.run_unit("OB-1").verdict is Outcome.PASS
            served = dashboard(url)
            page = open_page(browser, served.url).page
            station_id = seq.station.station.id
            here = f".tile[data-station='{station_id}']"
            page.wait_for_selector(f"{here} .outbox:has-text('outbox: empty')")
            field = page.inner_text(f"{here} .field")
            assert "surveyed field 48.00 µT" in field and "checked 48.02 µT" in field, field
            assert "before the batch's unit 1" in field and re.search(r"at \d\d:\d\d,", field), field

            def refused(source, target, run_id, new_id):  # the server refuses this run's rows
                from sqlalchemy.exc import DataError
                raise DataError("INSERT INTO phases", {}, ValueError("a value the server refuses"))

            monkeypatch.setattr(forwarding, "copy_children", refused)
            assert seq.run_unit("OB-2").verdict is Outcome.PASS
            page.wait_for_selector(f"{here} .outbox.queued:has-text('outbox: 1 record queued since')")
            assert page.evaluate("performance.navigation.type") == 0
        finally:
            seq.close()


def test_a_chart_page_sends_its_head_with_plotly_first_and_says_when_it_cannot_be_built():
    """The browser fetches and compiles plotly.js (a second on a first visit) while the server builds the
    charts, not after: the head naming plotly.js arrives while the page is still being built.  The page's own
    title follows; a page that could not be built says why in one line."""
    import threading

    from fastapi import FastAPI

    from magline.core.dashboard.app import PLOTLY_SRC, ChartPage, _chart_page

    built = threading.Event()

    def page() -> ChartPage:
        assert built.wait(30), "the test never let the page be built"
        return ChartPage("part P-1 & more </script>", "<h1>P-1</h1>")

    def broken() -> ChartPage:
        raise RuntimeError("the store went away")

    app = FastAPI()
    app.state.closing = threading.Event()
    app.get("/slow")(lambda: _chart_page("the process", page))
    app.get("/broken")(lambda: _chart_page("the process", broken))
    served = Served(app, free_port())
    try:
        with urllib.request.urlopen(served.url + "slow", timeout=30) as answer:
            head = b""
            while b"</head>" not in head:
                head += answer.read1(65536)
            assert f"<script src='{PLOTLY_SRC}'></script>".encode() in head and not built.is_set()
            built.set()
            rest = answer.read().decode()
        # the title as text, a closing tag in it kept from ending the script early
        assert rest == ('<body><script>document.title = "part P-1 & more <\\/script>";</script>'
                        "<h1>P-1</h1></body></html>")
        assert "dashboard.css" not in rest  # a report-styled page: the dashboard's frame brings its own
        with urllib.request.urlopen(served.url + "broken", timeout=30) as answer:
            text = answer.read().decode()
        assert text.endswith("<body><p class=note>This page could not be built: the store went away</p></body></html>")
    finally:
        served.stop()


def test_the_line_now_shows_a_slot_used_this_fortnight_and_counts_a_unit_begun_before_the_shift(tmp_path):
    """Read through the indexes a million-run store needs (a skip scan of a station's slots, the shift's
    range of its runs): a slot last used 20 days ago has no tile, the two used today have theirs, and a unit
    begun two hours before the shift and judged in it counts in this shift."""
    from datetime import UTC, timedelta

    from sqlalchemy import create_engine, update

    from magline.core.dashboard.line import line_now
    from magline.core.results.instants import stored_form
    from magline.core.results.tables import runs

    records = []
    for serial, slot in (("S-A", "A"), ("S-B", "B"), ("S-OLD", "C")):
        record = unit(serial, [], station_id="st-s")
        record.slot = slot
        records.append(record)
    records.append(unit("S-LONG", [], station_id="st-l"))
    write_units(tmp_path / "line.sqlite", records)
    now = datetime.now(UTC)
    shifts = shift_far_from_now()
    engine = create_engine(f"sqlite:///{tmp_path / 'line.sqlite'}")
    with engine.begin() as conn:
        old = stored_form(now - timedelta(days=20))
        conn.execute(update(runs).where(runs.c.serial == "S-OLD").values(started=old, finished=old))
        conn.execute(update(runs).where(runs.c.serial == "S-LONG").values(
            started=stored_form(shifts.start_of(now) - timedelta(hours=2))))
    with engine.connect() as conn:
        tiles = {(t["station_id"], t["slot"]): t for t in line_now(conn, now, shifts)["stations"]}
    engine.dispose()
    assert sorted(tiles) == [("st-l", None), ("st-s", "A"), ("st-s", "B")]
    assert tiles[("st-l", None)]["units"] == 1 and tiles[("st-s", "A")]["units"] == 1
