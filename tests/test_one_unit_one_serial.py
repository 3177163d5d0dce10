"""One unit, one serial (issue 43): what a line meets on its first shift made impossible, end to end —
a label scanned for two slots, a serial already under test elsewhere, a serial typed in lower case,
two stations in two folders, the batch line, and the console's last word on each unit."""

from __future__ import annotations

import json
import re
import threading
from importlib.resources import as_file, files

import pytest
from sqlalchemy import create_engine, select
from test_slots import MOCK_SLOTS, CountingMotion, counting_plugin

from magline.core.cli import main
from magline.core.plugins import hookimpl, load_plugins
from magline.core.results.tables import runs
from magline.core.sequencer import Sequencer
from magline.core.sequencer.hold import StationBusy, fixture_locks, holder_of, holding
from magline.core.station import load_station


def stored_serials(results) -> list[str]:
    engine = create_engine(f"sqlite:///{results}")
    try:
        with engine.connect() as conn:
            return [r.serial for r in conn.execute(select(runs.c.serial).order_by(runs.c.id))]
    finally:
        engine.dispose()


class HoldTheTumble:
    """Keeps a unit in its tumble until told to finish: another run is tried meanwhile."""

    def __init__(self) -> None:
        self.acquiring, self.finish = threading.Event(), threading.Event()

    @hookimpl
    def magline_acquisition_progress(self, run, attempt, samples, coverage, target):
        self.acquiring.set()
        self.finish.wait(30)


def held_unit(seq: Sequencer, serial: str, hold: HoldTheTumble) -> tuple[threading.Thread, list]:
    done: list = []
    worker = threading.Thread(target=lambda: done.append(seq.run_unit(serial)))
    worker.start()
    assert hold.acquiring.wait(30)
    return worker, done


def test_one_label_scanned_for_two_slots_is_refused_naming_both_and_records_nothing(make_station, monkeypatch,
                                                                                     capsys, tmp_path):
    path = make_station(MOCK_SLOTS)
    plugin = counting_plugin(CountingMotion())
    monkeypatch.setattr("magline.core.cli.load_plugins", lambda **how: load_plugins(extra=[plugin], **how))
    # on the command line: the same label for slots A and C, in another case
    assert main(["run", str(path), "--serial", "A=SL-1", "--serial", "C=sl-1"]) == 2
    err = capsys.readouterr().err
    assert "SL-1 is scanned for slots A and C: one serial is one unit — scan C's own label" in err
    assert stored_serials(tmp_path / "magline-demo-results.sqlite") == []
    # at the slot prompts: B's scan repeats A's label, so B is asked again at once
    answers = iter(["SL-1", "SL-1", "SL-2", ""])
    monkeypatch.setattr("builtins.input", lambda prompt: next(answers))
    assert main(["run", str(path)]) == 0
    captured = capsys.readouterr()
    assert "SL-1 is scanned for slots A and B: one serial is one unit — scan B's own label" in captured.err
    assert sorted(stored_serials(tmp_path / "magline-demo-results.sqlite")) == ["SL-1", "SL-2"]
    assert "batch: 2 units — 2 pass, 0 fail; first-pass yield 100% (2 of 2 judged units)" in captured.out


def test_a_serial_under_test_on_another_station_of_the_same_store_is_refused(make_station, tmp_path):
    """Two station files (two stations of a line) share one results store: the label of a unit under test
    on one is refused on the other, naming where it is under test; nothing is recorded for the second."""
    first_path = make_station({"results": {"path": "shared.sqlite"}})
    second_path = make_station({"station": {"id": "demo-02"}, "results": {"path": "shared.sqlite"}}, name="two.yaml")
    hold = HoldTheTumble()
    first = Sequencer(load_station(first_path), load_plugins(extra=[hold]), tmp_path, sleep=lambda s: None)
    worker, done = held_unit(first, "SH-1", hold)
    second = Sequencer(load_station(second_path), load_plugins(), tmp_path, sleep=lambda s: None)
    try:
        with pytest.raises(StationBusy) as busy:
            second.run_unit("sh-1")  # typed in lower case: the same unit
        assert "SH-1 is under test on station demo-01" in str(busy.value)
        assert "one serial is one unit — scan this unit's own label, or finish that test first" in str(busy.value)
    finally:
        hold.finish.set()
        worker.join(60)
        first.close()
    try:
        assert done and done[0].verdict == "pass", done
        assert stored_serials(tmp_path / "shared.sqlite") == ["SH-1"]  # nothing of demo-02's refused start
        assert second.run_unit("SH-1").verdict == "pass"  # once the first test is over, a re-test is allowed
    finally:
        second.close()


def test_serials_are_one_unit_whatever_the_case_typed_and_found_so(make_station, capsys, tmp_path):
    path = make_station()
    assert main(["run", str(path), "--serial", " sn-lower-01 "]) == 0
    assert main(["run", str(path), "--serial", "SN-LOWER-01"]) == 0
    assert stored_serials(tmp_path / "magline-demo-results.sqlite") == ["SN-LOWER-01", "SN-LOWER-01"]
    capsys.readouterr()
    assert main(["history", "Sn-Lower-01", "--station", str(path)]) == 0
    out = capsys.readouterr().out
    assert out.count(" PASS") == 2
    # its times to the second with their offset, as every other command prints them
    assert len(re.findall(r"^#\d+ \d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\+00:00 station ", out, re.M)) == 2, out
    assert main(["show", "sn-lower-01", "--station", str(path), "--json"]) == 0
    assert '"serial": "SN-LOWER-01"' in capsys.readouterr().out
    assert main(["report", "sn-lower-01", "--station", str(path), "-o", str(tmp_path / "r.html")]) == 0
    assert "SN-LOWER-01" in (tmp_path / "r.html").read_text(encoding="utf-8")
    assert main(["run", str(path), "--serial", "SN-OTHER"]) == 0
    capsys.readouterr()
    assert main(["export", "--station", str(path), "--serial", " Sn-Lower-01", "--format", "jsonl"]) == 0
    exported = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [r["serial"] for r in exported] == ["SN-LOWER-01", "SN-LOWER-01"]
    # a product whose serials keep their case: two units, each found as typed
    exact = make_station({"products": {"MOCK-100": {"serial_case": "exact"}}, "results": {"path": "exact.sqlite"}},
                         name="exact.yaml")
    assert main(["run", str(exact), "--serial", "sn-a"]) == 0
    assert main(["run", str(exact), "--serial", "SN-A"]) == 0
    assert stored_serials(tmp_path / "exact.sqlite") == ["sn-a", "SN-A"]
    capsys.readouterr()
    assert main(["history", "sn-a", "--station", str(exact)]) == 0
    assert capsys.readouterr().out.count(" PASS") == 1


def test_a_lower_case_pattern_under_upper_case_serials_is_a_station_file_mistake(make_station, capsys):
    path = make_station({"products": {"MOCK-100": {"serial_pattern": "sn-[a-z0-9]+"}}})
    assert main(["check", str(path)]) == 2
    err = capsys.readouterr().err
    assert f"{path}:" in err and "serial_pattern sn-[a-z0-9]+ asks for lower-case letters" in err


def test_two_demo_runs_in_two_folders_both_run_and_one_station_file_twice_is_refused(tmp_path, monkeypatch):
    """The embedded demo in two folders: two stores, an in-process mock — nothing shared, both run side by
    side.  The same station file twice shares its store and station slot: refused naming the folder and
    the store of the run that holds it."""
    with as_file(files("magline.stations") / "demo.yaml") as demo:
        station = load_station(demo)
    one, two = tmp_path / "one", tmp_path / "two"
    one.mkdir()
    two.mkdir()
    hold = HoldTheTumble()
    # the held unit need not tumble at a sensor's pace once released: what it holds is the station
    held_station = station.model_copy(deep=True)
    held_station.products["MOCK-100"].options["realtime"] = False
    # held through the other folder's whole demo run, however long: its first tumble once ran to the demo's
    # 60 s acquisition timeout on a loaded machine, the held unit's own 60 s ran out first, and its station
    # was free again when the test tried it
    held_station = held_station.model_copy(update={
        "acquisition": held_station.acquisition.model_copy(update={"timeout_s": 3600.0})})
    first = Sequencer(held_station, load_plugins(extra=[hold]), one, sleep=lambda s: None)
    worker, done = held_unit(first, "DEMO-A", hold)
    try:
        monkeypatch.chdir(two)  # the embedded demo keeps its files where magline runs
        assert main(["run", "--serial", "DEMO-B"]) == 0
        again = Sequencer(station, load_plugins(), one, sleep=lambda s: None)
        try:
            with pytest.raises(StationBusy) as busy:
                again.run_unit("DEMO-C")
        finally:
            again.close()
    finally:
        hold.finish.set()
        worker.join(60)
        first.close()
    text = str(busy.value)
    store = one.resolve() / "magline-demo-results.sqlite"
    assert text.startswith("station demo-01 is busy testing serial DEMO-A (")
    assert f"(folder {one.resolve()}, results {store}; pid " in text
    assert done[0].verdict == "pass"
    assert stored_serials(one / "magline-demo-results.sqlite") == ["DEMO-A"]
    assert stored_serials(two / "magline-demo-results.sqlite") == ["DEMO-B"]


def test_two_station_files_on_one_gimbal_share_its_lock_and_the_refusal_names_it(make_station):
    gimbal = {"motion": {"type": "gimbal", "options": {"resource": "TCPIP0::127.0.0.1::5030::SOCKET"}},
              "slots": MOCK_SLOTS["slots"]}
    first = load_station(make_station({**gimbal, "results": {"path": "a.sqlite"}}))
    # the same gimbal, written as a plain socket address in the second file
    second = load_station(make_station({**gimbal, "motion": {"type": "gimbal",
                                                             "options": {"resource": "tcp:127.0.0.1:5030"}},
                                        "station": {"id": "demo-02"}, "results": {"path": "b.sqlite"}},
                                       name="b.yaml"))
    with holding(fixture_locks(first), holder_of("G-1, G-2", "demo-01", "A, B", "/line/one", "a.sqlite")), \
            pytest.raises(StationBusy) as busy, \
            holding(fixture_locks(second), holder_of("G-3", "demo-02", "A")):
        raise AssertionError("two loads moved one gimbal")
    assert str(busy.value).startswith("the gimbal motion on tcp:127.0.0.1:5030 is busy: station demo-01 "
                                      "slot A, B is testing serial G-1, G-2 (folder /line/one, results a.sqlite;")


def test_the_batch_line_counts_runs_and_units_apart_and_each_unit_ends_with_what_to_do(make_station, monkeypatch,
                                                                                       capsys):
    path = make_station({"products": {"MOCK-100": {"limits": {"hard_iron_norm_ut": {"le": 1.0}}}}})  # every unit FAILs
    answers = iter(["LP-1", "lp-1", ""])  # the same unit twice (a re-test), typed in two cases
    monkeypatch.setattr("builtins.input", lambda prompt: next(answers))
    assert main(["run", str(path), "--loop"]) == 1
    out = capsys.readouterr().out.splitlines()
    closing = [line for line in out if line.startswith("FAIL LP-1")]
    assert closing == ["FAIL LP-1 — put the unit in the reject bin"] * 2
    verdicts = [i for i, line in enumerate(out) if "hard_iron_norm_ut" in line]
    assert all(out.index(closing[0]) > verdicts[0] for _ in closing)  # the verdict's last word is the action
    assert out[-1] == "batch: 2 runs of 1 unit — 0 pass, 2 fail; first-pass yield 0% (0 of 1 judged units)"


def test_a_serial_scanned_at_a_terminal_while_a_unit_runs_is_queued_and_said_never_echoed(tmp_path):
    """``--loop`` on a terminal (a pseudo-terminal here, as a line PC's console is): the label of the next
    unit scanned while the first tumbles is not echoed among the progress lines; the station says
    "next: LP-002 …" at once and starts it after the first unit's verdict, showing it under the question."""
    import os
    import pty
    import re
    import select
    import subprocess
    import sys
    import time

    from conftest import deep_update, demo_config

    cfg = deep_update(demo_config(), {"products": {"MOCK-100": {"options": {"realtime": True, "seed": 3}}},
                                      "acquisition": {"retry_delay_s": 0.0, "rate_hz": 100.0}})
    path = tmp_path / "station.yaml"
    import yaml

    path.write_text(yaml.safe_dump(cfg, sort_keys=False), encoding="utf-8")
    master, slave = pty.openpty()
    child = subprocess.Popen([sys.executable, "-m", "magline.core.cli", "run", str(path), "--loop"], cwd=tmp_path,
                             stdin=slave, stdout=slave, stderr=slave, close_fds=True,
                             env={**os.environ, "COLUMNS": "100", "LINES": "40", "TERM": "xterm"})
    os.close(slave)
    seen = bytearray()

    def until(pattern: str, timeout_s: float = 60.0) -> None:
        deadline = time.monotonic() + timeout_s
        while re.search(pattern, plain(seen)) is None:
            assert time.monotonic() < deadline, f"{pattern!r} not seen in:\n{plain(seen)[-3000:]}"
            ready, _, _ = select.select([master], [], [], 0.5)
            if ready:
                try:
                    seen.extend(os.read(master, 65536))
                except OSError:  # the child closed the terminal
                    break

    try:
        until(r"Scan the unit's serial number: ")
        os.write(master, b"LP-001\r")
        until(r"coverage")  # the first unit tumbles
        typed_at = len(plain(seen))
        os.write(master, b"LP-002\r")  # the next label, scanned too early
        until(r"next: LP-002 — scanned while a unit is under test")
        between = plain(seen)[typed_at:plain(seen).index("next: LP-002")]
        assert "LP-002" not in between  # the terminal did not echo it among the progress lines
        until(r"PASS LP-001 — put the unit with the good units")
        until(r"Scan the unit's serial number: LP-002")  # the queued label answers the question, shown
        until(r"PASS LP-002 — put the unit with the good units")
        until(r"Scan the unit's serial number: ")
        os.write(master, b"\r")  # an empty line ends the batch
        until(r"batch: 2 units — 2 pass")
        assert child.wait(30) == 0
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
        os.close(master)
    assert stored_serials(tmp_path / "magline-demo-results.sqlite") == ["LP-001", "LP-002"]


def plain(raw: bytearray) -> str:
    """What a terminal shows, as text: escape sequences (colours, cursor moves) removed."""
    import re

    return re.sub(r"\x1b\[[0-9;?]*[A-Za-z]|\x1b\][^\x07]*\x07|\r", "", raw.decode("utf-8", "replace"))


def test_a_countdown_on_a_terminal_rewrites_one_line_and_a_log_gets_a_line_every_few_seconds():
    import io
    from types import SimpleNamespace

    from rich.console import Console

    from magline.core.operator_ui.console import OperatorConsole

    run = SimpleNamespace(slot=None)
    for terminal in (True, False):
        out = io.StringIO()
        console = OperatorConsole(Console(file=out, width=80, force_terminal=terminal, color_system=None))
        for second in range(12):
            console.magline_waiting(run, "warming up before the tumble", float(second), 20.0)
        console.magline_wait_ended(run, "warming up before the tumble", 12.0)
        text = out.getvalue()
        if terminal:  # twelve counts, one line on the screen
            assert text.count("\n") == 1 and "8 s left of 20 s" in text.rsplit("\x1b", 1)[-1] + text
            assert text.count("warming up") >= 12
        else:
            assert [line.strip() for line in text.splitlines()] == [
                f"warming up before the tumble … {left} s left of 20 s" for left in (20, 15, 10)]


def test_the_screen_refuses_a_load_naming_one_serial_twice_and_names_the_slot_to_scan_again(make_station):
    """The station screen's slot load: the same label in two slot fields is refused before anything starts,
    with the slot whose field the page selects for the next scan (screen.js focuses it)."""
    import urllib.error
    import urllib.request

    from test_station_screen import Served, free_port

    from magline.core.operator_ui.screen.serve import build

    path = make_station(MOCK_SLOTS)
    app, runner = build(load_station(path), path.parent, load_plugins(extra=[counting_plugin(CountingMotion())]),
                        None)
    served = Served(app, free_port())

    def start(serials: dict) -> tuple[int, dict]:
        request = urllib.request.Request(served.url + "api/start", data=json.dumps({"serials": serials}).encode(),
                                         headers={"Content-Type": "application/json"}, method="POST")
        try:
            with urllib.request.urlopen(request, timeout=10) as answer:
                return answer.status, json.loads(answer.read())
        except urllib.error.HTTPError as refused:
            return refused.code, json.loads(refused.read())

    try:
        status, answer = start({"A": "SL-7", "B": "", "C": "sl-7"})
        assert status == 400
        assert answer == {"error": "SL-7 is scanned for slots A and C: one serial is one unit — scan C's own label",
                          "slot": "C"}
        assert not runner.busy()
        status, answer = start({"A": "SL-8", "B": "SL/9"})
        assert status == 400 and answer["slot"] == "B" and "SL/9" in answer["error"]
    finally:
        served.stop()
        runner.close()
    assert stored_serials(path.parent / "magline-demo-results.sqlite") == []
