"""Unit and batch reports open offline in a real browser (Debian's Chromium through playwright):
their charts render with data, they ask nothing of the network, and a screenshot is kept."""

from __future__ import annotations

import io

import pytest
from browser import colour_pixels, drawn_points, new_page, open_page, plots_with_data, screenshot
from rich.console import Console
from simstation import attempt_rows

from magline.core.cli import main
from magline.core.reports.capability_figures import BAR_COLOUR, LINE_COLOUR, UNIT_COLOUR

OFFLINE = ("file://", "data:", "blob:", "about:")


def test_a_unit_report_is_self_contained_and_shows_the_whole_run(make_station, tmp_path, browser, capsys):
    station = make_station()
    assert main(["run", str(station), "--serial", "REP-1"]) == 0
    capsys.readouterr()
    out = tmp_path / "out" / "rep-1.html"
    assert main(["report", "REP-1", "--station", str(station), "-o", str(out)]) == 0
    assert capsys.readouterr().out.strip() == str(out)
    assert out.stat().st_size <= 6_000_000  # plotly.js embedded is most of it

    opened = open_page(browser, out.as_uri())
    plots = plots_with_data(opened.page)
    used = next(a for a in attempt_rows(tmp_path / "magline-demo-results.sqlite", "REP-1") if a["accepted"])
    assert plots["residual"] >= 0.9 * used["samples"] and plots["samples3d"] > 0 and plots["coverage3d"] > 0
    assert opened.outside(OFFLINE) == []  # not one request beyond the file
    text = opened.page.inner_text("body")
    head = text[:200]
    assert "REP-1" in head and "PASS" in head  # identity and verdict at the top
    for shown in ("hard_iron_norm_ut", "[—, 150]", "below the target 60%", "accepted",
                  "read back after power cycle", "MAG_OFS_X", "field reference", "48 µT", "mean", "p2p"):
        assert shown in text, shown
    screenshot(opened.page, tmp_path / "unit-report.png")
    assert (tmp_path / "unit-report.png").stat().st_size > 10_000
    # issue 30: the identity table has no blank header row; the empty bins are drawn with a glyph
    # Chromium's fonts have (WebGL draws 3D markers as font glyphs: "x" showed as tofu boxes)
    first = opened.page.evaluate("document.querySelector('table tr').innerText")
    assert first.strip().startswith("run")
    symbols = opened.page.evaluate("document.getElementById('coverage3d').data.map((t) => t.marker && t.marker.symbol)")
    assert "x" not in symbols and "circle" in symbols


def test_a_failed_unit_report_marks_the_measurement_and_shows_nothing_written(make_station, tmp_path, browser):
    station = make_station({"products": {"MOCK-100": {"limits": {"hard_iron_norm_ut": {"le": 50.0}}}}})
    assert main(["run", str(station), "--serial", "BAD-1"]) == 1
    out = tmp_path / "bad.html"
    assert main(["report", "1", "--station", str(station), "-o", str(out)]) == 0  # by run id
    opened = open_page(browser, out.as_uri())
    assert plots_with_data(opened.page)["residual"] > 0
    assert opened.outside(OFFLINE) == []
    failed_row = opened.page.inner_text("tr.fail")
    assert "hard_iron_norm_ut" in failed_row and "[—, 50]" in failed_row
    assert "nothing was written to the unit" in opened.page.inner_text("body")
    screenshot(opened.page, tmp_path / "failed-report.png")


def test_the_station_writes_each_units_report_with_review_flags_marked(make_station, tmp_path, browser):
    from magline.core.operator_ui.console import OperatorConsole
    from magline.core.plugins import load_plugins
    from magline.core.sequencer import Sequencer
    from magline.core.station import load_station

    marginal = {"hard_iron_norm_ut": {"le": 80.0, "marginal": 10.0}}  # 73.7 µT sits in the 70–80 band
    station = make_station({"results": {"reports": "reports"}, "products": {"MOCK-100": {"limits": marginal}}})
    shown = io.StringIO()
    console = OperatorConsole(Console(file=shown, width=140, color_system=None))
    seq = Sequencer(load_station(station), load_plugins(extra=[console]), station.parent, sleep=lambda s: None)
    try:
        record = seq.run_unit("AUTO-1")
    finally:
        seq.close()
    assert record.report == str(tmp_path / "reports" / "AUTO-1-run1.html") and not record.report_error
    assert f"report: {record.report}" in shown.getvalue()
    opened = open_page(browser, f"file://{record.report}")
    assert plots_with_data(opened.page)["coverage3d"] > 0
    review_row = opened.page.inner_text("tr.review")
    assert "hard_iron_norm_ut" in review_row and "within the marginal band" in review_row


def test_a_report_that_cannot_be_written_is_said_and_the_unit_keeps_its_verdict(make_station, tmp_path):
    from magline.core.plugins import load_plugins
    from magline.core.record import Outcome
    from magline.core.sequencer import Sequencer
    from magline.core.station import load_station

    (tmp_path / "blocked").write_text("a file where the report folder should be", encoding="utf-8")
    station = make_station({"results": {"reports": "blocked"}})
    seq = Sequencer(load_station(station), load_plugins(), station.parent, sleep=lambda s: None)
    try:
        record = seq.run_unit("NOREP-1")
    finally:
        seq.close()
    assert record.verdict is Outcome.PASS and record.store and not record.report
    assert record.report_error.startswith("report not written:")


def test_the_batch_report_draws_every_chart_offline(make_station, tmp_path, browser, capsys):
    for i, serial in enumerate(("B-1", "B-2", "B-3", "B-4")):
        station = make_station(seed=40 + i)  # four different units (one seed would repeat one unit: constants)
        assert main(["run", str(station), "--serial", serial]) == 0
    page = tmp_path / "spc.html"
    many = ("hard_iron_x_ut", "hard_iron_y_ut", "hard_iron_z_ut", "hard_iron_norm_ut", "axis_ratio",
            "soft_iron_offdiag_max", "residual_rms_ut", "residual_max_ut", "field_error_pct", "hard_iron_sigma_ut",
            "direction_sigma_deg", "mounting_error_deg", "inclination_deg", "residual_ut.std")
    asked = [a for name in many for a in ("--measurement", name)]  # many charts on one page (issue 30)
    assert main(["spc", "--station", str(station), "--html", str(page), *asked]) == 0
    assert "hard_iron_x_ut" in capsys.readouterr().out
    opened = open_page(browser, page.as_uri())
    plots = plots_with_data(opened.page)
    assert plots["chart-hard_iron_x_ut"] >= 4 and len(plots) >= 10
    # issue 30: drawn, not only carried — every chart shows its units' points, and no WebGL context
    # was lost (Chromium keeps 16; the page had 18 charts with no points in the first ones)
    drawn = drawn_points(opened.page)
    charts = [k for k in drawn if k.startswith("chart-")]
    assert len(charts) >= 10 and all(drawn[k] >= 4 for k in charts), drawn
    assert not [m for m in opened.console if "webgl" in m.lower() or m.startswith("error")], opened.console
    assert opened.outside(OFFLINE) == []
    assert "first-pass yield" in opened.page.inner_text("body")
    screenshot(opened.page, tmp_path / "spc.png")

    # the page is painted between two charts (it once showed nothing until its last chart was drawn): a
    # frame comes between every two, and the first drawn is in view
    watched = new_page(browser)
    watched.add_init_script("""window.__seen = [];
        document.addEventListener('plotted', (e) => window.__seen.push(e.target.id));
        requestAnimationFrame(function tick() { window.__seen.push('frame'); requestAnimationFrame(tick); });""")
    watched.goto(page.as_uri())
    watched.wait_for_function("!document.querySelector('.plot-pending')")
    seen = watched.evaluate("window.__seen")
    drawn_in_turn = [s for s in seen if s != "frame"]
    assert sorted(drawn_in_turn) == sorted(plots) and len(drawn_in_turn) == len(set(drawn_in_turn))
    between = seen[seen.index(drawn_in_turn[0]):seen.index(drawn_in_turn[-1]) + 1]
    assert all(between[i + 1] == "frame" for i in range(len(between) - 1) if between[i] != "frame"), seen
    in_view = watched.evaluate("""[...document.querySelectorAll('.plotly-graph-div')].filter((e) => {
        const box = e.getBoundingClientRect(); return box.bottom > 0 && box.top < innerHeight; }).map((e) => e.id)""")
    in_order = watched.eval_on_selector_all(".plotly-graph-div", "els => els.map((e) => e.id)")
    assert drawn_in_turn[:len(in_view)] == in_view if in_view else drawn_in_turn == in_order
    watched.close()
    linked = new_page(browser)
    linked.add_init_script("""window.__seen = [];
        document.addEventListener('plotted', (e) => window.__seen.push(e.target.id));""")
    linked.goto(page.as_uri() + "#chart-residual_max_ut")  # a link to a chart far down: it is drawn first
    linked.wait_for_function("!document.querySelector('.plot-pending')")
    seen = linked.evaluate("window.__seen")
    # first, or second where the first was picked before the browser scrolled to the link's chart
    assert seen.index("chart-residual_max_ut") <= 1 and len(seen) == len(plots), seen
    linked.close()


@pytest.mark.parametrize("wanted", ["NO-SUCH-UNIT", "999"])
def test_report_of_an_unknown_run_says_so(make_station, capsys, wanted):
    """As ``magline show`` and ``history`` say it: nothing found is exit 1 with the store named; 2 is for a
    command that could not read at all."""
    station = make_station()
    assert main(["run", str(station), "--serial", "K-1"]) == 0
    capsys.readouterr()
    assert main(["report", wanted, "--station", str(station)]) == 1
    err = capsys.readouterr().err
    store = station.parent / "magline-demo-results.sqlite"
    assert f"no run or serial '{wanted}' in {store} (magline history lists a unit's runs)" in err
    assert main(["show", wanted, "--station", str(station)]) == 1 and capsys.readouterr().err == err


def test_the_batch_report_reads_like_a_capability_study_and_a_point_opens_its_unit(make_station, tmp_path, browser,
                                                                                 capsys):
    """Issue 45: per characteristic the I-MR chart against unit time, the histogram with the limits and the
    fitted curve, the normal probability plot and the capability summary; FPY per day and the failure
    Pareto; a click on a point opens that unit's report (written by the station, offline); the limit
    labels never overprint the axis' tick labels; a report the folder lost is written again by
    ``--with-reports`` and opens with its charts drawn.  Checked in Chromium on what it drew."""
    for i, serial in enumerate(("C-1", "C-2", "C-3", "C-4", "C-5")):
        station = make_station({"results": {"reports": "reports"}, "acquisition": {"stop": "samples"}},
                               seed=60 + i)
        assert main(["run", str(station), "--serial", serial]) == 0
    page = tmp_path / "study" / "spc.html"
    (station.parent / "reports" / "C-1-run1.html").unlink()  # lost: --with-reports writes it again
    capsys.readouterr()
    assert main(["spc", "--station", str(station), "--html", str(page), "--with-reports"]) == 0
    assert "1 unit report(s) written" in capsys.readouterr().err
    opened = open_page(browser, page.as_uri())
    plots = plots_with_data(opened.page)
    assert {"chart-hard_iron_norm_ut", "shape-hard_iron_norm_ut", "fpy-over-time"} <= set(plots)
    drawn = drawn_points(opened.page)
    # the probability plot: one marker per unit (the line is not a marker)
    shape_points = opened.page.evaluate("""() => document.getElementById('shape-hard_iron_norm_ut')
        .querySelectorAll('.scatterlayer .trace:first-child .point').length""")
    bars = opened.page.evaluate("""() => document.getElementById('shape-hard_iron_norm_ut')
        .querySelectorAll('.barlayer .point').length""")
    assert shape_points == 5 and bars >= 1 and drawn["chart-hard_iron_norm_ut"] >= 5
    # and by its pixels: the histogram's bars, the probability plot's five unit markers (each ~6 px across),
    # the fitted curve and the normal line in blue
    seen = colour_pixels(opened.page, "#shape-hard_iron_norm_ut", {"bars": BAR_COLOUR, "units": UNIT_COLOUR,
                                                                   "curves": LINE_COLOUR}, within=24,
                         path=tmp_path / "shape.png")
    assert seen["bars"] > 2000 and seen["units"] > 5 * 12 and seen["curves"] > 150, seen
    # the limit 80 µT beyond five units 0.1 µT apart is named at the edge, not drawn with bars a pixel wide
    assert "USL 150 →" in opened.page.inner_text("#shape-hard_iron_norm_ut")
    text = opened.page.inner_text("body")
    assert "shape and method" in text and "control limits" in text and "provisional" in text

    # the limits' labels sit inside the plot: none overlaps a tick label of the y axis
    overlaps = opened.page.evaluate("""() => {
        const out = [];
        document.querySelectorAll('.js-plotly-plot').forEach(plot => {
            const labels = [...plot.querySelectorAll('.annotation-text')].filter(
                t => /^(LSL|USL)/.test(t.textContent)).map(t => t.getBoundingClientRect());
            const ticks = [...plot.querySelectorAll('.ytick text')].map(t => t.getBoundingClientRect());
            const meet = (a, b) => a.left < b.right && b.left < a.right && a.top < b.bottom && b.top < a.bottom;
            for (const a of labels) for (const b of ticks) if (meet(a, b)) out.push(plot.id);
            // nor do the chart's own labels overprint each other (UCL, centre and LCL squeezed into one
            // line under a limit far away)
            const all = [...plot.querySelectorAll('.annotation-text')].map(
                t => [t.textContent, t.getBoundingClientRect()]);
            all.forEach(([ta, a], i) => all.slice(i + 1).forEach(([tb, b]) => {
                if (meet(a, b)) out.push(plot.id + ": " + ta + " / " + tb); }));
        });
        return out;}""")
    assert overlaps == []
    # the yield's own axis reads in round percentages (aligned to the units axis it read 33.3, 66.5, 99.8)
    assert opened.page.evaluate("""() => [...document.querySelectorAll('#fpy-over-time .y2tick text')]
        .map(t => t.textContent)""") == ["0", "25", "50", "75", "100"]
    # a specification limit far from the units is named at the chart's edge, the control band fills it
    assert "USL 150 ↑" in opened.page.inner_text("#chart-hard_iron_norm_ut")

    # a click on the first unit's point opens its report, from the station's reports folder
    point = opened.page.locator("#chart-hard_iron_norm_ut .scatterlayer .trace:first-child .point").first
    point.scroll_into_view_if_needed()
    box = point.bounding_box()
    with opened.page.expect_navigation():
        opened.page.mouse.click(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    assert opened.page.url.endswith("/reports/C-1-run1.html") and opened.page.url.startswith("file://")
    assert "C-1" in opened.page.inner_text("h1")
    assert plots_with_data(opened.page)  # its charts drew with the plotly.js it shares with the folder
    assert opened.outside(OFFLINE) == []
    screenshot(opened.page, tmp_path / "study.png")


def test_the_capability_table_keeps_each_figure_on_one_line_and_the_text_table_says_units(make_station, tmp_path,
                                                                                           browser, capsys):
    """Issue 64: on a laptop-wide page the capability table's figures wrapped mid-figure ("µT" under its
    number, "[—, 150]" over two lines); the text table had no units.  Measured in Chromium: each figure's text
    is one line box."""
    for i, serial in enumerate(("W-1", "W-2", "W-3")):
        station = make_station(seed=70 + i)
        assert main(["run", str(station), "--serial", serial]) == 0
    page = tmp_path / "spc.html"
    assert main(["spc", "--station", str(station), "--html", str(page)]) == 0
    out = capsys.readouterr().out
    header = next(line for line in out.splitlines() if line.startswith("measurement ") and " σ within " in line)
    assert header.split()[:3] == ["measurement", "unit", "n"]
    assert any(line.startswith("hard_iron_norm_ut") and " µT " in line for line in out.splitlines())
    opened = open_page(browser, page.as_uri(), viewport=(900, 800))
    wrapped = opened.page.evaluate("""() => {
        const table = [...document.querySelectorAll('h2')].find(h => h.textContent === 'Capability').nextElementSibling;
        return [...table.querySelectorAll('td.num')].filter(td => {
            const range = document.createRange(); range.selectNodeContents(td);
            return new Set([...range.getClientRects()].map(r => Math.round(r.top))).size > 1;
        }).map(td => td.textContent);
    }""")
    assert wrapped == []


def test_two_groups_at_the_same_yield_both_stay_visible():
    """Issue 64: carol's first-pass-yield point sat exactly under dave's.  Each group's markers are a size
    smaller and of their own symbol, drawn over the one before."""
    from types import SimpleNamespace

    from magline.core.reports.trend_figures import yield_over_time

    point = SimpleNamespace(period="2026-11-20", first_pass=3, first_runs=3)
    trends = SimpleNamespace(fpy={"operator": {"carol": [point], "dave": [point]}})
    fig = yield_over_time(trends, "operator", by_shift=False)
    carol, dave = fig.data
    assert carol.y == dave.y  # the same yield, the same place …
    assert carol.marker.size > dave.marker.size and carol.marker.symbol != dave.marker.symbol  # … both seen


def test_a_chart_that_cannot_be_drawn_says_so_and_the_others_are_drawn(browser, tmp_path):
    """The page draws its charts one after another: one that fails (here data that is not a figure) must not
    leave the ones after it undrawn — it says so in its place."""
    import plotly.graph_objects as go

    from magline.core.reports.page import figure_html, shared_plotly, write_page

    good = figure_html(go.Figure(go.Scatter(x=[1, 2, 3], y=[3, 1, 2])), "after")
    broken = ('<div id="broken" class="plotly-graph-div plot-pending" style="height:300px"></div>'
              '<script type="application/json" data-plot="broken">{"data": [</script>')
    page = write_page(tmp_path / "page.html", "one broken chart", [broken, good], shared_plotly(tmp_path))
    opened = open_page(browser, page.as_uri())
    assert plots_with_data(opened.page) == {"after": 3}
    assert opened.page.inner_text("#broken").startswith("this chart could not be drawn: SyntaxError")
