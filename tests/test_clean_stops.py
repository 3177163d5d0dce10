"""Clean stops and a truthful record through a shift: Ctrl-C / SIGTERM, killed processes, serial
sources, re-tests, where records are kept."""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
from conftest import REPO, deep_update, demo_config
from simstation import attempt_rows

from magline.core.results.sqlite_store import SqliteSink


def realtime_station(tmp_path: Path, changes: dict | None = None) -> Path:
    """The demo station as a line runs it: the mock DUT streams in real time (600 readings at 200 Hz)."""
    cfg = deep_update(demo_config(), {"products": {"MOCK-100": {"options": {"seed": 3, "motions": ["hand_tumble"]}}},
                                      "acquisition": {"retry_delay_s": 0.0}})
    cfg = deep_update(cfg, changes or {})
    path = tmp_path / "station.yaml"
    path.write_text(yaml.safe_dump(cfg, sort_keys=False, allow_unicode=True), encoding="utf-8")
    return path


def start(args: list[str], cwd: Path) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "magline.core.cli", *args], cwd=cwd, stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})


def read_until(proc: subprocess.Popen, marker: str, timeout_s: float = 60.0) -> str:
    """Read the child's stdout line by line until ``marker`` appears (the pipe blocks; the child's
    own deadline bounds the wait)."""
    seen = ""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            break
        seen += line
        if marker in line:
            return seen
    raise AssertionError(f"{marker!r} never appeared; output so far:\n{seen}")


def runs(db: Path) -> list[tuple]:
    with sqlite3.connect(db) as con:
        return con.execute("SELECT serial, verdict, aborted_phase, cause FROM runs ORDER BY id").fetchall()


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["ctrl-c", "sigterm"])
def test_a_signal_mid_acquisition_aborts_the_unit_keeps_its_readings_and_prints_the_batch(tmp_path, sig):
    station = realtime_station(tmp_path)
    proc = start(["run", str(station), "--loop"], tmp_path)
    proc.stdin.write("A-1\n")
    proc.stdin.flush()
    assert "─ PASS ─" in read_until(proc, "record: ")  # the first unit passes (its verdict panel)
    proc.stdin.write("A-2\n")
    proc.stdin.flush()
    read_until(proc, "attempt 1:")  # the second is acquiring
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 2
    assert "Traceback" not in err and "KeyboardInterrupt" not in err
    assert "ABORTED" in out
    assert "batch: 2 units — 1 pass, 0 fail, 1 aborted; first-pass yield 100% (1 of 1 judged units)" in out
    db = tmp_path / "magline-demo-results.sqlite"
    (s1, v1, _, _), (s2, v2, phase, cause) = runs(db)
    assert (s1, v1) == ("A-1", "pass") and (s2, v2, phase) == ("A-2", "aborted", "acquire")
    assert cause.startswith("stopped by ")
    with sqlite3.connect(db) as con:
        (samples, refused), = con.execute("SELECT a.samples, a.refused FROM attempts a JOIN runs r ON a.run_id = r.id"
                                          " WHERE r.serial = 'A-2'").fetchall()
    assert 0 < samples < 600 and refused.startswith("interrupted: stopped by")


def test_a_killed_station_leaves_its_run_incomplete_never_running(tmp_path):
    station = realtime_station(tmp_path)
    proc = start(["run", str(station), "--serial", "K-1"], tmp_path)
    read_until(proc, "attempt 1:")
    proc.kill()
    proc.wait(timeout=30)
    db = tmp_path / "magline-demo-results.sqlite"
    assert runs(db)[0][1] == "running"  # what the killed process left
    SqliteSink(db).close()  # the next station (or `magline history`) opening the store
    (serial, verdict, _, cause), = runs(db)
    assert (serial, verdict) == ("K-1", "incomplete") and "ended before the run finished" in cause


def test_a_station_killed_after_an_attempt_keeps_that_attempts_raw_data(tmp_path):
    """The demo's first attempt (a single-axis spin) is stored before the retry; a SIGKILL during the
    retry leaves it there, and the run is marked incomplete, never passed."""
    station = realtime_station(tmp_path, {"products": {"MOCK-100": {"options": {
        "motions": ["single_axis", "hand_tumble"]}}}})
    proc = start(["run", str(station), "--serial", "K-2"], tmp_path)
    read_until(proc, "attempt 2:")
    proc.kill()
    proc.wait(timeout=30)
    db = tmp_path / "magline-demo-results.sqlite"
    SqliteSink(db).close()
    (serial, verdict, _, _), = runs(db)
    assert (serial, verdict) == ("K-2", "incomplete")
    (attempt,) = attempt_rows(db, "K-2")
    assert attempt["attempt"] == 1 and attempt["samples"] == len(attempt["raw"]) >= 100  # every reading it had


def test_loop_without_terminal_or_serials_tests_nothing_and_says_so(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "magline.core.cli", "run", "--loop"], cwd=tmp_path,
                          stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and "no unit tested" in proc.stderr
    assert "DEMO-" not in proc.stdout  # no serial invented


def test_serials_read_from_a_pipe_end_their_prompt_line(tmp_path):
    """Issue 30: a scanner script or a log has no terminal echo: the prompt's line ends with the serial."""
    proc = subprocess.run([sys.executable, "-m", "magline.core.cli", "run", "--loop"], cwd=tmp_path,
                          input="PIPE-1\n", capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    lines = proc.stdout.splitlines()
    assert "Scan the unit's serial number: PIPE-1" in lines  # not run together with the next line
    assert "Scan the unit's serial number: " in lines  # EOF at the next prompt ends the batch, on its own line
    assert lines[-1].startswith("batch: 1 unit")


def test_history_names_the_store_it_searched_and_never_creates_one(tmp_path, monkeypatch, capsys):
    from magline.core.cli import main

    monkeypatch.chdir(tmp_path)
    assert main(["history", "NOPE-1"]) == 1
    err = capsys.readouterr().err
    assert f"no results store at {tmp_path / 'magline-demo-results.sqlite'}" in err and "embedded demo" in err
    assert not (tmp_path / "magline-demo-results.sqlite").exists()


def test_fit_piped_into_head_exits_quietly(tmp_path):
    csv = tmp_path / "raw.csv"
    import numpy as np

    from magline.core.fit.samples_csv import RawSamples, format_samples
    from magline.sim.truth import SensorTruth, motion_directions
    rng = np.random.default_rng(1)
    truth = SensorTruth(hard_iron_ut=np.array([10.0, -5.0, 20.0]), soft_iron=np.eye(3), noise_ut=0.3)
    mag = truth.read(motion_directions("hand_tumble", 600, rng, np.array([20.0, 0.0, 40.0])) * 48.0, rng)
    csv.write_text(format_samples(RawSamples(mag_ut=mag, t_ms=np.arange(600) * 5.0)), encoding="utf-8")
    proc = subprocess.run(f"{sys.executable} -m magline.core.cli fit {csv} | head -1", shell=True,
                          capture_output=True, text=True, timeout=60)
    assert proc.stdout.startswith("model") and proc.stderr == ""


def test_a_simulator_whose_reader_went_away_stops_quietly_on_sigterm():
    """A plugin's command (``magline sim``) started by a program that then died: its last line goes to a
    broken pipe, and it stops without a traceback."""
    proc = subprocess.Popen([sys.executable, "-m", "magline.core.cli", "sim", "gimbal", "--listen",
                             "tcp:127.0.0.1:0"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stdout.readline().startswith("listening on")
    proc.stdout.close()  # the reader is gone
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=60) == 0
    assert proc.stderr.read() == ""


def test_example_stations_that_are_different_stations_have_different_ids():
    ids = {}
    for path in sorted((REPO / "stations").glob("*.yaml")):
        ids.setdefault(yaml.safe_load(path.read_text(encoding="utf-8"))["station"]["id"], []).append(path.name)
    assert all(len(names) == 1 for names in ids.values()), ids


def test_a_signal_during_a_slot_load_aborts_every_slot_and_keeps_each_ones_readings(tmp_path):
    """Issue 31: the stop signal (systemctl stop, a PC shutdown) while a load of slots tumbles: every unit
    of the load is ABORTED with its readings, restored, and the station exits — none left running."""
    station = realtime_station(tmp_path, {
        "slots": [{"id": "A", "part": "MOCK-100", "options": {"storage": str(tmp_path / "a.json")}},
                  {"id": "B", "part": "MOCK-100", "options": {"storage": str(tmp_path / "b.json"), "seed": 9}}],
        "acquisition": {"stop": "samples"}})
    proc = start(["run", str(station), "--serial", "A=SL-A", "--serial", "B=SL-B"], tmp_path)
    read_until(proc, "attempt 1")  # the load is tumbling
    time.sleep(0.5)
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 2, out + err
    assert "Traceback" not in err
    rows = runs(tmp_path / "magline-demo-results.sqlite")
    assert sorted((s, v, phase) for s, v, phase, _ in rows) == [("SL-A", "aborted", "acquire"),
                                                                 ("SL-B", "aborted", "acquire")]
    for serial in ("SL-A", "SL-B"):
        (attempt,) = attempt_rows(tmp_path / "magline-demo-results.sqlite", serial)
        assert attempt["samples"] > 0 and attempt["refused"].startswith("interrupted: stopped by")


def test_ctrl_c_while_the_command_starts_is_one_line_and_the_abort_s_exit_code(monkeypatch, capsys):
    """Issue 65: a Ctrl-C in the half second of imports before ``magline run --loop`` reached its prompt
    printed a Python traceback.  The entry point holds the handler before anything heavy is imported: an
    interrupt inside the command's imports, or inside any command, ends with one line and exit 2."""
    import importlib.abc

    from magline.core import entry

    class InterruptedImport(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path, target=None):
            if name == "magline.core.cli":
                raise KeyboardInterrupt
            return None

    monkeypatch.delitem(sys.modules, "magline.core.cli", raising=False)
    monkeypatch.setattr(sys, "meta_path", [InterruptedImport(), *sys.meta_path])
    assert entry.main() == entry.ABORT_EXIT
    err = capsys.readouterr().err
    assert err == "magline: interrupted (Ctrl-C): nothing more was done\n"


def test_ctrl_c_at_the_serial_prompt_is_one_line_and_exit_2(tmp_path):
    """At the prompt: the prompt's line says it, and nothing else is printed."""
    import signal

    proc = subprocess.Popen([sys.executable, "-m", "magline.core.entry", "run", "--loop"], cwd=tmp_path,
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        seen = ""
        while "Scan the unit's serial number" not in seen:  # the prompt is what it waits for, not a time
            char = proc.stdout.read(1)
            assert char, proc.stderr.read()
            seen += char
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 2
    lines = (seen + out).strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Scan the unit's serial number")
    assert lines[0].endswith("stopped by Ctrl-C: no unit under test")
    assert "Traceback" not in err and err.strip() == ""
