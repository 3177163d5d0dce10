"""What the operator and the record are told: one coverage figure, every problem of a station file
at once, re-tests said, library chatter kept out of the console, countdowns, a complete verdict panel."""

from __future__ import annotations

import json
import logging
import sqlite3

import numpy as np
import pytest
from rich.console import Console
from simstation import FAST_SENSOR_HZ, attempt_rows, write_station

from magline.core.cli import main
from magline.core.fit.samples_csv import format_samples
from magline.core.operator_ui.console import OperatorConsole
from magline.core.plugins import hookimpl, load_plugins
from magline.core.record import Outcome
from magline.core.sequencer import Sequencer
from magline.core.station import load_station
from magline.sim import create_sim


def run_with(path, *listeners, serial="U1"):
    seq = Sequencer(load_station(path), load_plugins(extra=list(listeners)), path.parent, sleep=lambda s: None)
    try:
        return seq.run_unit(serial)
    finally:
        seq.close()


class Progress:
    def __init__(self):
        self.seen: dict[int, list[float]] = {}

    @hookimpl
    def magline_acquisition_progress(self, run, attempt, samples, coverage, target):
        self.seen.setdefault(attempt, []).append(coverage)


def test_coverage_is_one_figure_that_never_decreases(make_station, tmp_path, capsys):
    path = make_station()
    progress = Progress()
    record = run_with(path, progress)
    assert record.verdict is Outcome.PASS, record.cause
    assert len(progress.seen) == 2  # the demo's single-axis spin, then the tumble
    assert record.attempts[0].refused == f"coverage {record.attempts[0].coverage:.0%} below the target 60%"
    for attempt, values in progress.seen.items():
        assert values == sorted(values), f"attempt {attempt}: the live coverage went down"
        assert values[-1] == record.attempts[attempt - 1].coverage  # the bar ends on the attempt's figure
    coverage = next(m for m in record.measurements if getattr(m, "name", "") == "coverage")
    assert coverage.value == record.attempts[-1].coverage  # the measurement is the same number
    assert f"coverage {record.attempts[-1].coverage:.0%}" in "\n".join(p for ph in record.phases for p in ph.log)
    accepted = [a for a in attempt_rows(tmp_path / "magline-demo-results.sqlite", record.serial) if a["accepted"]]
    csv = tmp_path / "accepted.csv"
    csv.write_text(format_samples(accepted[0]["raw"]), encoding="utf-8")
    capsys.readouterr()
    assert main(["fit", str(csv), "--json", "--bins", "40"]) == 0
    assert json.loads(capsys.readouterr().out)["coverage"]["fraction"] == coverage.value  # `magline fit` agrees


STAGED = """\
station:
  id: s1
  line: L1
  location: {latitude_deg: 47.0, longitude_deg: 8.0}
products:
  P1:
    backend: ardupilot
    connectoin: "tcp:127.0.0.1:5760"
    options:
      connect_timeout_s: -1
acquisition:
  samples: "600"
limits:
  residual_rms: {le: 1.0}
"""


def test_check_reports_every_problem_of_a_file_in_one_pass(tmp_path, capsys):
    path = tmp_path / "staged.yaml"
    path.write_text(STAGED, encoding="utf-8")
    assert main(["check", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"{path}:8: products.P1.connectoin: unknown key (did you mean 'connection'?)",
        f"{path}:10: products.P1.options.connect_timeout_s: Input should be greater than 0",
        f"{path}:12: acquisition.samples: Input should be a valid integer (got str '600')",
        f"{path}:14: limits.residual_rms: unknown measurement 'residual_rms' (did you mean 'residual_rms_ut'?); "
        "known: " + err[3].split("known: ")[1],
    ]


def test_a_misspelt_backend_gets_a_suggestion(tmp_path, capsys):
    path = tmp_path / "s.yaml"
    path.write_text(STAGED.replace("backend: ardupilot", "backend: ardupilott"), encoding="utf-8")
    assert main(["check", str(path)]) == 2
    assert "unknown DUT backend 'ardupilott' (did you mean 'ardupilot'?)" in capsys.readouterr().err


def test_the_record_phase_is_stored_with_its_real_outcome(make_station, tmp_path):
    record = run_with(make_station())
    with sqlite3.connect(tmp_path / "magline-demo-results.sqlite") as db:
        (outcome, duration), = db.execute("SELECT outcome, duration_s FROM phases WHERE name = 'record'").fetchall()
    assert outcome == "pass" and duration > 0
    assert record.store == f"{tmp_path / 'magline-demo-results.sqlite'} run {record.run_id}"


def test_a_retest_of_a_passed_unit_is_allowed_and_said(make_station, tmp_path):
    path = make_station()
    console = OperatorConsole(Console(record=True, width=200, highlight=False))
    first = run_with(path, serial="R-1")
    second = run_with(path, console, serial="R-1")
    assert first.verdict is Outcome.PASS and second.verdict is Outcome.PASS
    assert (first.earlier_runs, second.earlier_runs, second.earlier_passes) == (0, 1, 1)
    text = console.console.export_text()
    assert "Re-test: R-1 already passed" in text and "this is test 2 of this unit" in text
    with sqlite3.connect(tmp_path / "magline-demo-results.sqlite") as db:
        assert [r[0] for r in db.execute("SELECT earlier_runs FROM runs ORDER BY id")] == [0, 1]


def test_library_chatter_goes_to_the_record_not_the_console(make_station, capfd):
    class Chatty:
        @hookimpl
        def magline_phase_started(self, run, phase):
            if phase == "persist":
                logging.getLogger("magline.px4.mavsdk").warning("Sending again, retries to do: 3")

    record = run_with(make_station(), Chatty())
    assert record.verdict is Outcome.PASS
    out = capfd.readouterr()
    assert "Sending again" not in out.out + out.err
    persist = next(p for p in record.phases if p.name == "persist")
    assert any("Sending again, retries to do: 3" in line for line in persist.log)


def test_the_verdict_panel_shows_every_measurement_the_matrix_and_the_store(make_station, tmp_path):
    path = make_station({"limits": {"axis_ratio": {"le": 1.15, "marginal": 0.05}}})
    console = OperatorConsole(Console(record=True, width=200, highlight=False))
    record = run_with(path, console)
    text = console.console.export_text()
    assert record.verdict is Outcome.PASS
    axis_ratio = next(m for m in record.measurements if getattr(m, "name", "") == "axis_ratio")
    assert "! axis_ratio" in text and "REVIEW (marginal)" in text and "[—, 1.15]" in text
    assert "✓ residual_rms_ut" in text and "µT" in text and "· field_ut" in text
    assert "soft iron [" in text and f"record: {tmp_path / 'magline-demo-results.sqlite'} run 1" in text
    assert f"{axis_ratio.value:.4g}" in text and str(axis_ratio.value) not in text  # rounded, never 17 digits


class Waits:
    """Every wait hook, in the order called, with the phases around them."""

    def __init__(self):
        self.ticks: list[tuple[str, float, float | None]] = []
        self.events: list[tuple[str, str]] = []

    @hookimpl
    def magline_waiting(self, run, what, elapsed_s, limit_s):
        self.ticks.append((what, elapsed_s, limit_s))
        self.events.append(("tick", what))

    @hookimpl
    def magline_wait_ended(self, run, what, waited_s):
        self.events.append(("ended", what))

    @hookimpl
    def magline_phase_finished(self, run, phase, result):
        self.events.append(("finished", phase))


def test_a_power_cycle_shows_a_countdown(tmp_path):
    waits = Waits()
    with create_sim("ardupilot", "tcp:127.0.0.1:0", mag_rate_hz=FAST_SENSOR_HZ, workdir=tmp_path / "fc", seed=11,
                    boot_time_s=2.5, speed=5.0) as sim:
        station = write_station("ardupilot-sim.yaml", tmp_path, sim.address,
                                {"connect_timeout_s": 5.0, "boot_timeout_s": 12.0, "prearm_wait_s": 0.3})
        record = run_with(station, waits)
    assert record.verdict is Outcome.PASS, record.cause
    assert waits.ticks and all(limit == 12.0 for _, _, limit in waits.ticks)
    assert all("waiting for the unit to boot" in what for what, _, _ in waits.ticks)
    elapsed = [e for _, e, _ in waits.ticks]
    assert elapsed == sorted(elapsed) and np.all(np.diff(elapsed) > 0.5)
    # the wait says its end once, after its last tick and before the verify phase goes on to its checks
    ended = [i for i, (kind, _) in enumerate(waits.events) if kind == "ended"]
    assert len(ended) == 1 and waits.events[ended[0]] == ("ended", waits.ticks[0][0])
    assert all(kind != "tick" for kind, _ in waits.events[ended[0]:])
    assert ("finished", "verify") in waits.events[ended[0] + 1:]


def test_a_wait_ends_once_after_its_last_tick_also_when_what_it_waited_for_fails():
    """``RunContext.waiting``: ticks from the timer thread while the block runs, then one
    ``magline_wait_ended``, also when the block raises; no tick comes after the end."""
    import threading
    from types import SimpleNamespace

    import pytest

    from magline.core.sequencer.context import RunContext

    events, ticked = [], threading.Event()

    def waiting(run, what, elapsed_s, limit_s):
        events.append(("tick", what, limit_s))
        if sum(e[0] == "tick" for e in events) >= 3:
            ticked.set()

    def wait_ended(run, what, waited_s):
        events.append(("ended", what, waited_s))

    run = SimpleNamespace(plugins=SimpleNamespace(hook=SimpleNamespace(magline_waiting=waiting,
                                                                       magline_wait_ended=wait_ended)))
    with pytest.raises(TimeoutError), RunContext.waiting(run, "power cycle", 30.0, tick_s=0.01):
        assert ticked.wait(10)
        raise TimeoutError("the unit did not come back")
    ends = [e for e in events if e[0] == "ended"]
    assert len(ends) == 1 and ends[0][1] == "power cycle" and ends[0][2] > 0
    assert events[-1][0] == "ended"
    seen = len(events)
    threading.Event().wait(0.1)  # ten tick periods: a timer still running would have added ticks
    assert len(events) == seen


def test_a_part_the_station_does_not_build_is_refused_in_words_and_leaves_no_record(make_station):
    """Issue 43: like an empty serial, a part the station does not build is refused before a record
    exists, naming the parts it builds (no Python class name, no ERROR unit in the yield)."""
    from magline.core.serials import PartRefused

    path = make_station()
    seq = Sequencer(load_station(path), load_plugins(), path.parent)
    try:
        with pytest.raises(PartRefused) as refused:
            seq.run_unit("U9", part="NOPE")
        assert seq.sink.history("U9") == []
    finally:
        seq.close()
    assert str(refused.value) == ("part 'NOPE' is not built on station demo-01: its parts are MOCK-100 — choose "
                                  "one of them")


def test_a_compass_is_titled_by_its_place_its_sensor_where_known_and_its_device_id():
    """'compass 2: HMC5883 (458786)'; a sensor known only by its place reads 'compass 1 (396809)', not
    'compass 1: (396809)' with nothing after the colon, nor 'compass 1: compass 1'."""
    from magline.core.record import RunRecord

    record = RunRecord(serial="T-1", part="P", station_id="S", line="L", operator="op", software_version="0",
                       limit_hash="h")
    record.unit_info = {"magnetometers": [{"device_id": 396809, "label": "compass 1"},
                                          {"device_id": 458786, "label": "HMC5883", "prefix": "mag2"}]}
    assert record.sensor_titles() == {"": "compass 1 (396809)", "mag2.": "compass 2: HMC5883 (458786)"}
