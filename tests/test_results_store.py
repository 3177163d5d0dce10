"""The results store: one versioned schema (SQLAlchemy Core + Alembic), old files upgraded in place,
newer stores refused."""

from __future__ import annotations

import shutil
import socket
import sqlite3
from pathlib import Path

import numpy as np
import pytest
from simstation import attempt_rows
from sqlalchemy import text

from magline.core.faults import StationFault
from magline.core.fit.samples_csv import parse_samples
from magline.core.results import schema_version
from magline.core.results.sqlite_store import SqliteSink

FIXTURES = Path(__file__).parent / "fixtures"
LEGACY = FIXTURES / "results-magline-0.1.sqlite"  # written by the hand-written SQLite sink of magline 0.1


def test_a_store_from_before_migrations_is_upgraded_in_place_keeping_every_run(tmp_path):
    path = tmp_path / "station.sqlite"
    shutil.copy(LEGACY, path)
    with sqlite3.connect(path) as db:
        before = db.execute("SELECT id, serial, verdict, calibration FROM runs ORDER BY id").fetchall()
        raw_before = db.execute("SELECT run_id, attempt, raw_csv FROM attempts ORDER BY run_id, attempt").fetchall()
        failed_before = db.execute("SELECT name, value FROM measurements WHERE verdict = 'fail'").fetchall()
    assert [r[1:3] for r in before] == [("LEGACY-1", "pass"), ("LEGACY-2", "fail")]
    sink = SqliteSink(path)
    assert sink.revision == schema_version.head_revision()
    history = sink.history("LEGACY-2")
    sink.close()
    with sqlite3.connect(path) as db:
        after = db.execute("SELECT id, serial, verdict, calibration FROM runs ORDER BY id").fetchall()
        uuids = [u for (u,) in db.execute("SELECT run_uuid FROM runs")]
        (version,), = db.execute("SELECT version_num FROM alembic_version").fetchall()
    raw_after = [(a["run_id"], a["attempt"], a["raw"]) for serial in ("LEGACY-1", "LEGACY-2")
                 for a in attempt_rows(path, serial)]
    assert after == before  # every run kept
    assert [r[:2] for r in raw_after] == [r[:2] for r in raw_before]  # and every attempt's raw data,
    for (_, _, csv_text), (_, _, samples) in zip(raw_before, raw_after, strict=True):  # now a float32 array
        old = parse_samples(csv_text)
        assert len(samples) == len(old) > 0
        np.testing.assert_allclose(samples.mag_ut, old.mag_ut, rtol=1e-6, atol=1e-4)
        np.testing.assert_array_equal(samples.t_ms, old.t_ms)
    assert len(set(uuids)) == 2 and all(len(u) == 36 for u in uuids)  # each old run got its identity
    assert version == schema_version.head_revision()
    assert [(f["name"], f["value"]) for f in history[0]["failed"]] == failed_before
    SqliteSink(path).close()  # opening again changes nothing


def test_a_store_written_by_a_newer_magline_is_refused(tmp_path):
    path = tmp_path / "new.sqlite"
    SqliteSink(path).close()
    with sqlite3.connect(path) as db:
        db.execute("UPDATE alembic_version SET version_num = '9999'")
    with pytest.raises(StationFault, match=r"schema revision 9999, newer than this magline knows .*: upgrade magline"):
        SqliteSink(path)


def test_a_store_that_cannot_be_written_is_a_clear_station_error(tmp_path):
    blocker = tmp_path / "not-a-dir"
    blocker.write_text("x", encoding="utf-8")
    with pytest.raises(StationFault, match="results store"):
        SqliteSink(blocker / "results.sqlite")


def test_a_new_store_is_exactly_the_store_the_migrations_make(tmp_path):
    """A new file is a copy of an empty store migrated once per process (core/results/new_sqlite.py): its
    tables, indexes and their SQL are those of a file migrated step by step, at the same revision."""
    from sqlalchemy import create_engine

    def objects(path: Path) -> list:
        with sqlite3.connect(path) as db:
            found = db.execute("SELECT type, name, tbl_name, sql FROM sqlite_master ORDER BY type, name").fetchall()
            return [found, db.execute("SELECT version_num FROM alembic_version").fetchall()]

    migrated = tmp_path / "migrated.sqlite"
    engine = create_engine(f"sqlite:///{migrated}")
    schema_version.upgrade(engine, str(migrated))
    engine.dispose()
    SqliteSink(tmp_path / "first.sqlite").close()
    SqliteSink(tmp_path / "second.sqlite").close()  # from the process's template
    assert objects(tmp_path / "first.sqlite") == objects(migrated) == objects(tmp_path / "second.sqlite")
    assert len(objects(migrated)[0]) > 20 and objects(migrated)[1] == [(schema_version.HEAD,)]


def test_a_new_store_never_replaces_a_store_another_station_made_meanwhile(tmp_path, monkeypatch):
    """Two stations sharing a store file start at once: the one whose copy comes second keeps the
    other's store (and its unit), and leaves no staged copy behind."""
    from magline.core.results import new_sqlite

    path = tmp_path / "shared.sqlite"
    real_link = new_sqlite.os.link

    def other_station_first(source, target):
        shutil.copy(source, target)  # the other station made the store and recorded a unit in it
        with sqlite3.connect(target) as db:
            db.execute("INSERT INTO runs (run_uuid, serial, part, verdict) VALUES ('u-1', 'THEIRS-1', 'P', 'pass')")
        real_link(source, target)

    monkeypatch.setattr(new_sqlite.os, "link", other_station_first)
    assert new_sqlite.create_at_head(path) is False
    with sqlite3.connect(path) as db:
        assert db.execute("SELECT serial FROM runs").fetchall() == [("THEIRS-1",)]
    assert sorted(p.name for p in tmp_path.iterdir() if not p.name.endswith(("-wal", "-shm"))) == ["shared.sqlite"]
    assert new_sqlite.create_at_head(path) is False  # a store that exists is never made again


# ------------------------------------------------------------------ both engines


def sql_station(make_station, store_url, monkeypatch, changes=None, name="station.yaml"):
    monkeypatch.setenv("MAGLINE_TEST_DB_URL", store_url)
    return make_station({"results": {"sink": "sql", "url_env": "MAGLINE_TEST_DB_URL"}, **(changes or {})}, name=name)


def test_a_station_writes_and_traces_units_on_each_engine(make_station, store_url, monkeypatch, capsys):
    from magline.core.cli import main
    from magline.core.plugins import load_plugins
    from magline.core.record import Outcome
    from magline.core.sequencer import Sequencer
    from magline.core.station import load_station

    good = sql_station(make_station, store_url, monkeypatch)
    bad = sql_station(make_station, store_url, monkeypatch,
                      {"products": {"MOCK-100": {"limits": {"hard_iron_norm_ut": {"le": 10.0}}}}}, name="bad.yaml")
    records = []
    for path, serial in ((good, "E-1"), (bad, "E-1"), (good, "E-2")):
        seq = Sequencer(load_station(path), load_plugins(), path.parent, sleep=lambda s: None)
        try:
            records.append(seq.run_unit(serial))
        finally:
            seq.close()
    assert [r.verdict for r in records] == [Outcome.PASS, Outcome.FAIL, Outcome.PASS]
    assert records[1].earlier_runs == 1 and records[1].earlier_passes == 1  # one store, seen across runs
    assert "not-a-secret" not in records[0].store and ("***" in records[0].store) == ("postgresql" in store_url)
    assert "forwarded from the outbox" in records[0].store  # committed locally first, then forwarded
    capsys.readouterr()
    assert main(["history", "E-1", "--station", str(good)]) == 0
    out = capsys.readouterr()
    assert "PASS" in out.out and "FAIL" in out.out and "hard_iron_norm_ut" in out.out
    assert "not-a-secret" not in out.out + out.err


def test_a_run_whose_writer_died_is_marked_incomplete_on_each_engine(store_url, monkeypatch):
    from sqlalchemy import create_engine

    from magline.core.record import RunRecord
    from magline.core.results import store as store_module
    from magline.core.results.store import SqlStore

    store = SqlStore(create_engine(store_url), "test store")
    monkeypatch.setattr(store_module, "owner", lambda: f"{socket.gethostname()}:999999999")
    record = RunRecord(serial="K-1", part="P", station_id="s", line="L", operator="", software_version="0",
                       limit_hash="h")
    store.begin(record)  # a writer with a pid that does not exist
    store.close()
    reopened = SqlStore(create_engine(store_url), "test store")
    (run,) = reopened.history("K-1")
    reopened.close()
    assert run["verdict"] == "incomplete" and "ended before the run finished" in run["cause"]


def test_a_newer_schema_is_refused_on_each_engine(store_url):
    from sqlalchemy import create_engine, text

    from magline.core.results.store import SqlStore

    SqlStore(create_engine(store_url), "test store").close()
    engine = create_engine(store_url)
    with engine.begin() as conn:
        conn.execute(text("UPDATE alembic_version SET version_num = '9999'"))
    engine.dispose()
    with pytest.raises(StationFault, match="newer than this magline"):
        SqlStore(create_engine(store_url), "test store")


def test_the_server_url_comes_from_the_environment_and_its_password_is_never_shown(make_station, monkeypatch):
    from magline.core.results.sql_store import server_store

    with pytest.raises(StationFault, match=r"MAGLINE_NOT_SET .* is not set"):
        server_store("MAGLINE_NOT_SET")
    monkeypatch.setenv("MAGLINE_BAD_DB", "postgresql+psycopg://line:hunter2@127.0.0.1:1/results")
    with pytest.raises(StationFault) as info:
        server_store("MAGLINE_BAD_DB")
    assert "hunter2" not in str(info.value) and "127.0.0.1" in str(info.value)


def test_show_and_export_read_the_store_on_each_engine(make_station, store_url, monkeypatch, capsys):
    """``magline show`` prints a whole record; ``magline export`` streams filtered runs as CSV / JSON
    lines, raw samples on request."""
    import csv
    import io
    import json
    import re

    from magline.core.cli import main

    good = sql_station(make_station, store_url, monkeypatch)
    bad = sql_station(make_station, store_url, monkeypatch,
                      {"products": {"MOCK-100": {"limits": {"hard_iron_norm_ut": {"le": 10.0}}}}}, name="bad.yaml")
    assert main(["run", str(good), "--serial", "X-1"]) == 0
    assert main(["run", str(bad), "--serial", "X-2"]) == 1
    capsys.readouterr()

    assert main(["show", "1", "--station", str(good)]) == 0
    out = capsys.readouterr().out
    assert "unit X-1" in out and "PASS" in out and "\n  written: " in out and "\n  read_back: " in out
    assert "attempts:" in out and "not used (coverage" in out  # the demo's first, single-axis attempt
    persistence = next(line for line in out.splitlines() if line.startswith("persistence: "))
    numbers = re.findall(r"-?\d+\.\d+", persistence)
    assert numbers and all(len(n.lstrip("-").replace(".", "").lstrip("0")) <= 4 for n in numbers)  # 4 digits
    assert main(["show", "1", "--station", str(good), "--json"]) == 0
    whole = json.loads(capsys.readouterr().out)
    assert whole["serial"] == "X-1" and len(whole["attempts"]) == 2 and whole["params"]["written"]
    assert len(whole["station_hash"]) == 16 and whole["reference_field_ut"] == 48.0
    assert whole["params"]["echoed"] == pytest.approx(whole["params"]["written"])
    assert main(["show", whole["run_uuid"], "--station", str(good), "--json"]) == 0  # by UUID too
    assert json.loads(capsys.readouterr().out)["id"] == 1
    # by serial (its latest run), whatever spaces were typed; each attempt says why its tumble ended
    assert main(["show", " X-2 ", "--station", str(good), "--json"]) == 0
    x2 = json.loads(capsys.readouterr().out)
    assert main(["show", " X-2 ", "--station", str(good)]) == 0
    out = capsys.readouterr().out
    assert "unit X-2" in out and "stalled after" in out and "accepted — " in out
    assert "determined after" in out and "predicted heading σ" in out
    assert main(["show", "NOPE", "--station", str(good)]) == 1
    err = capsys.readouterr().err
    assert "no run or serial 'NOPE'" in err and "magline history lists a unit's runs" in err

    assert main(["export", "--station", str(good)]) == 0
    rows = list(csv.DictReader(io.StringIO(capsys.readouterr().out)))
    assert [(r["serial"], r["verdict"]) for r in rows] == [("X-1", "pass"), ("X-2", "fail")]
    assert rows[1]["failed"] == "hard_iron_norm_ut" and float(rows[0]["hard_iron_norm_ut"]) > 0
    assert main(["export", "--station", str(good), "--verdict", "fail", "--format", "jsonl"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 1 and json.loads(lines[0])["measurements"]["hard_iron_norm_ut"]["verdict"] == "fail"
    assert main(["export", "--station", str(good), "--since", "2999-01-01"]) == 0
    assert len(capsys.readouterr().out.splitlines()) == 1  # the header only
    assert main(["export", "--station", str(good), "--raw", "--part", "MOCK-100"]) == 0
    samples = list(csv.DictReader(io.StringIO(capsys.readouterr().out)))
    stored = {r["serial"]: sum(a["samples"] for a in r["attempts"]) for r in (whole, x2)}
    assert len(samples) == sum(stored.values()) and {s["serial"] for s in samples} == {"X-1", "X-2"}
    assert {s["sensor"] for s in samples} == {"mag1"}  # the mock has one magnetometer
    assert abs(float(samples[0]["mag_x_ut"])) < 500


def test_a_record_that_cannot_be_stored_is_never_reported_as_stored(make_station):
    """Disk full, a read-only store: the unit is not booked as passed, the operator is told."""
    from rich.console import Console

    from magline.core.operator_ui.console import OperatorConsole
    from magline.core.plugins import hookimpl, load_plugins
    from magline.core.record import Outcome
    from magline.core.sequencer import Sequencer
    from magline.core.station import load_station

    class FullDisk(SqliteSink):
        def finish(self, record):
            raise StationFault(f"results store {self.where}: storing the run's record failed: "
                               "database or disk is full")

    class Sinks:
        @hookimpl
        def magline_register_result_sinks(self, register):
            register("full-disk", lambda station, where, entry, options: FullDisk(where / "full.sqlite"))

    path = make_station({"results": {"sink": "full-disk"}})
    console = OperatorConsole(Console(record=True, width=200, highlight=False))
    seq = Sequencer(load_station(path), load_plugins(extra=[Sinks(), console]), path.parent, sleep=lambda s: None)
    try:
        record = seq.run_unit("FULL-1")
    finally:
        seq.close()
    assert record.verdict is Outcome.ERROR and record.store == ""
    assert "the record could not be stored" in record.cause and "disk is full" in record.cause
    assert "record: NOT stored" in console.console.export_text()


def test_the_latest_units_of_a_part_are_read_as_aligned_series(make_station, store_url, monkeypatch):
    """What statistics read, on both engines: the latest runs oldest first, each numeric measurement
    an array aligned with them, the limits they were judged against, attempts per run."""
    import numpy as np
    from sqlalchemy import create_engine

    from magline.core.cli import main
    from magline.core.results.reading import RunFilter
    from magline.core.results.series import load_series

    path = sql_station(make_station, store_url, monkeypatch)
    for serial in ("L-1", "L-2", "L-3"):
        assert main(["run", str(path), "--serial", serial]) == 0
    tight = sql_station(make_station, store_url, monkeypatch,
                        {"products": {"MOCK-100": {"limits": {"hard_iron_norm_ut": {"le": 10.0}}}}},
                        name="tight.yaml")
    assert main(["run", str(tight), "--serial", "L-4"]) == 1
    engine = create_engine(store_url)
    with engine.connect() as conn:
        failing = load_series(conn, RunFilter(part="MOCK-100"), last=2, with_attempts=True)
        series = load_series(conn, RunFilter(part="MOCK-100", verdict="pass"), last=2, with_attempts=True)
        assert len(load_series(conn, RunFilter(part="NO-SUCH-PART"), last=2)) == 0
        only = load_series(conn, RunFilter(part="MOCK-100"), names=["coverage"])
        stored = {(r.run_id, r.value) for r in conn.execute(text(
            "SELECT run_id, value FROM measurements WHERE name = 'hard_iron_x_ut'"))}
    engine.dispose()
    assert [r["serial"] for r in series.runs] == ["L-2", "L-3"]  # the two latest, oldest first
    assert {"hard_iron_x_ut", "coverage", "residual_ut.std"} <= set(series.values)
    x = series.values["hard_iron_x_ut"]
    assert {(r["id"], v) for r, v in zip(series.runs, x, strict=True)} <= stored and np.all(np.isfinite(x))
    assert series.limits["hard_iron_norm_ut"].high is not None and series.limits["hard_iron_x_ut"].unit == "µT"
    assert series.attempts.tolist() == [2, 2]  # the demo spins once about one axis, then tumbles
    assert list(only.values) == ["coverage"] and len(only) == 4
    assert failing.failed == [[], ["hard_iron_norm_ut"]] and [r["verdict"] for r in failing.runs] == ["pass", "fail"]


def test_every_migration_downgrades_and_upgrades_again_to_the_same_schema(tmp_path):
    """The column migrations' downgrades are derived from their upgrades (core/results/migrations/
    columns.py): down to the baseline and up again leaves the schema exactly as a fresh store's."""
    from alembic import command
    from sqlalchemy import create_engine, inspect

    def schema(engine) -> dict:
        found = inspect(engine)
        return {t: sorted((c["name"], str(c["type"]), c["nullable"]) for c in found.get_columns(t))
                for t in sorted(found.get_table_names())}

    path = tmp_path / "round.sqlite"
    SqliteSink(path).close()
    engine = create_engine(f"sqlite:///{path}")
    try:
        fresh = schema(engine)
        with engine.begin() as conn:
            command.downgrade(schema_version._config(conn), "0001")
        down = schema(engine)
        assert "review" not in {c for c, _, _ in down["runs"]} and "stopped" not in {c for c, _, _ in down["attempts"]}
        with engine.begin() as conn:
            command.upgrade(schema_version._config(conn), "head")
        assert schema(engine) == fresh
    finally:
        engine.dispose()


def test_the_export_has_columns_for_the_compasses_the_units_have_and_says_test_review_and_params(
        make_station, capsys):
    """Issue 45: a one-compass station's CSV had 60 empty mag2/mag3 columns and no word on re-tests,
    review flags or what was written; integers came as 2.0."""
    import csv
    import io

    from magline.core.cli import main
    from magline.testing import run_unit

    station = make_station({"acquisition": {"stop": "samples"}})
    first = run_unit(station, "EX-1")
    again = run_unit(station, "EX-1")
    assert first.verdict.value == again.verdict.value == "pass"
    from magline.core.results.sqlite_store import SqliteSink
    from magline.testing import make_record

    flagged = make_record("EX-2", part="MOCK-100", verdict="pass")
    flagged.review = [{"name": "hard_iron_norm_ut", "reason": "4.2σ above the recent units"},
                      {"name": "axis_ratio", "reason": "3.9σ"}]
    store = SqliteSink(station.parent / "magline-demo-results.sqlite")
    store.finish(flagged)
    store.close()
    capsys.readouterr()
    assert main(["export", "--station", str(station)]) == 0
    header, *rows = list(csv.reader(io.StringIO(capsys.readouterr().out)))
    assert not [h for h in header if h.startswith(("mag2", "mag3", "mag1-"))]  # the mock has one compass
    assert {"test", "review", "params_written", "soft_iron_11", "limit_hash"} <= set(header)
    cells = [dict(zip(header, row, strict=True)) for row in rows]
    assert [c["test"] for c in cells] == ["first", "re-test 1", "first"]
    assert cells[2]["review"] == "axis_ratio;hard_iron_norm_ut"
    assert cells[0]["attempts"] == "2" and cells[0]["id"] == "1"  # integers as integers
    written = dict(item.split("=") for item in cells[0]["params_written"].split(";"))
    assert set(written) == set(first.params_written)
    assert all(float(written[k]) == pytest.approx(v, rel=1e-6) for k, v in first.params_written.items())
    assert cells[0]["review"] == ""


def test_show_and_the_unit_report_read_as_a_document_not_as_stored_json(make_station, capsys, tmp_path):
    """Issue 45: ``show`` printed the unit's facts, its mounting and the power cycle as Python dicts and
    raw JSON; the unit report put dicts in table cells and showed two coverage figures (88 % beside
    85 %).  Now every part is words with units, and the coverage picture is the judged figure."""
    import re

    from magline.core.cli import main
    from magline.testing import run_unit

    station = make_station()
    record = run_unit(station, "DOC-1")
    assert record.verdict.value == "pass"
    capsys.readouterr()
    assert main(["show", "DOC-1", "--station", str(station)]) == 0
    out = capsys.readouterr().out
    assert not re.search(r"[{}\[\]']|\bTrue\b|\bNone\b", out.split("measurements:")[0]), out  # no repr above
    tail = out.split("station file")[1]
    assert not re.search(r"[{}']|\bTrue\b|\bFalse\b|\bNone\b", tail), tail
    assert "magnetometers:\n  mag1  magnetometer, device id " in out
    assert re.search(r"mounting:\n  mag1 +orientation 0 \(configured 0\), \d\.\d\d° ± \d\.\d\d° from it", out)
    assert ("persistence: power cycle link-reboot; calibration kept in parameters (the autopilot parameter "
            "storage); time to heartbeat ") in out and "read back as written" in out
    # a short time in ms, as a person reads it (the mock's reboot answers within a millisecond: it said
    # "0.000124 s")
    assert re.search(r"time to heartbeat \d+(\.\d+)? (ms|s)\b", out)
    assert not re.search(r"time to heartbeat 0\.\d+ s\b", out)
    # what was written and what the firmware echoed are one value where it holds float32: shown as one
    staged = {stage: dict(item.split("=") for item in values.split(", "))
              for stage, values in re.findall(r"^  (written|echoed|read_back): (.*)$", out, re.M)}
    assert "params (parameters as the firmware holds them: single precision (float32)" in out
    assert staged["written"] and all(staged["echoed"].get(k, v) == v == staged["read_back"].get(k, v)
                                     for k, v in staged["written"].items())

    page = tmp_path / "doc.html"
    assert main(["report", "DOC-1", "--station", str(station), "-o", str(page)]) == 0
    text = page.read_text(encoding="utf-8")
    body = text.split("<script")[0] + "".join(part.split("</script>", 1)[-1] for part in text.split("<script")[1:])
    assert "{&#x27;" not in body and "{'" not in body and "&#x27;prefix" not in body  # no dict in a cell
    accepted = record.attempts[-1]
    shown = re.findall(r"coverage: \d+ of \d+ direction bins \((\d+)%\)", text)
    assert shown == [f"{round(accepted.coverage * 100)}"]  # the 3D picture says the judged figure
    assert "<h3>Power cycle</h3>" in text and "as written" in text


def test_the_head_revision_a_store_is_recognised_by_is_alembic_s_own_head():
    """A store at HEAD is opened without alembic (one query): a migration added without moving HEAD
    would leave stores unmigrated, so HEAD is held to the newest migration script."""
    assert schema_version.head_revision() == schema_version.HEAD, (
        "a migration was added: set schema_version.HEAD to its revision")


def test_a_store_at_the_head_is_opened_without_alembic(tmp_path):
    import subprocess
    import sys

    path = tmp_path / "at-head.sqlite"
    SqliteSink(path).close()
    probe = ("import sys; from pathlib import Path; from magline.core.results.sqlite_store import SqliteSink; "
             f"SqliteSink(Path({str(path)!r})).close(); print('alembic' in sys.modules)")
    assert subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True).stdout.strip() \
        == "False"


def test_a_series_reads_every_value_back_bit_for_bit_on_each_engine(store_url):
    """The series comes back as text parsed by NumPy on both engines (the drivers' Python floats cost
    more than the query): every double must survive it exactly, a failure be placed on its run, and a
    run without the measurement stay NaN."""
    from sqlalchemy import create_engine

    from magline.core.measurements import Numeric, Verdict
    from magline.core.record import Outcome, RunRecord
    from magline.core.results.reading import RunFilter
    from magline.core.results.store import SqlStore

    # what measurements take (SQLite's own printf rounds a few doubles beyond 1e±200 in the last bit)
    awkward = [0.1 + 0.2, 1e-12, -2.2250738585e-8, 123456.78901234567, 48.000000000000014, 6.02214076e23,
               -1.0 / 3.0]
    store = SqlStore(create_engine(store_url), "test store")
    for i, value in enumerate([*awkward, None]):
        record = RunRecord(serial=f"B-{i}", part="P", station_id="s", line="L", operator="", software_version="0",
                           limit_hash="h")
        record.verdict = Outcome.FAIL if i == 2 else Outcome.PASS
        if value is not None:
            record.measurements.append(Numeric("field_ut", value, "µT", None, None,
                                               Verdict.FAIL if i == 2 else Verdict.PASS))
        store.finish(record)
    series = store.series(RunFilter(part="P"), with_attempts=True)
    store.close()
    read = series.values["field_ut"]
    assert [float(v).hex() for v in read[:-1]] == [v.hex() for v in awkward] and np.isnan(read[-1])
    assert series.failed[2] == ["field_ut"] and not any(series.failed[i] for i in (0, 1, 3, 4, 5, 6, 7))


def test_a_parameter_is_shown_as_the_float32_the_firmware_holds():
    """0.95090135 written and its float32 echoed read "0.9509014" beside "0.9509013" at 7 digits."""
    import numpy as np

    from magline.core.text import param_text

    written = 0.95090135
    echoed = float(np.float32(written))
    assert param_text(written) == param_text(echoed) == "0.9509013"
    assert param_text(2.0) == "2" and param_text(-1500) == "-1500" and param_text(None) == "—"
    assert float(np.float32(param_text(1e-7 / 3))) == float(np.float32(1e-7 / 3))  # it is that float32
