"""The ACME plugins tested only with magline.testing, as their author would."""

from __future__ import annotations

import json

import pytest
from magline.testing import check_dut_backend, check_result_sink, check_station

from acme_magline.dut import AcmeDut, AcmeOptions
from acme_magline.simulator import AcmeSim
from acme_magline.sink import JsonLinesSink


@pytest.fixture
def board(tmp_path):
    sim = AcmeSim(tmp_path / "flash.json").start()
    yield sim
    sim.stop()


def test_the_backend_meets_magline_s_dut_contract(board):
    check_dut_backend(lambda: AcmeDut(AcmeOptions(), board.connection), board.field_ut, samples=400, rate_hz=100.0,
                      prepare_params=["AUTOCAL"], hard_iron_ut=board.truth.hard_iron_ut, unsaved_writes="lost")


def test_the_sink_meets_magline_s_results_contract(tmp_path):
    check_result_sink(lambda folder: JsonLinesSink(folder / "units.jsonl"), tmp_path)


ACME_PART = {"backend": "acme", "connection": "", "options": {"boot_timeout_s": 5.0},
             "limits": {"hard_iron_norm_ut": {"le": 150.0}}}


def test_a_unit_runs_end_to_end_into_both_stores(board, magline_station, magline_run, tmp_path):
    station = magline_station(replace={
        "products": {"ACME-7": {**ACME_PART, "connection": board.connection}}, "default_part": "ACME-7",
        "acquisition": {"samples": 400, "rate_hz": 100.0, "coverage_bins": 40, "coverage_target": 0.6,
                        "retries": 1, "retry_delay_s": 0.0, "timeout_s": 20.0},
        "results": [{"sink": "sqlite", "path": "units.sqlite"},
                    {"sink": "jsonl", "options": {"path": "plant/units.jsonl"}}]})
    record = magline_run(station, "ACME-0001")
    assert record.verdict == "pass", record.cause
    assert record.params_read_back["OFS_X"] == pytest.approx(-board.truth.hard_iron_ut[0] * 10, abs=10.0)  # mG, added
    lines = [json.loads(x) for x in (tmp_path / "plant" / "units.jsonl").read_text().splitlines()]
    assert [x["verdict"] for x in lines if x["type"] == "run"] == ["pass"]
    assert json.loads((tmp_path / "flash.json").read_text())["AUTOCAL"] == 1.0  # restored in flash too


def test_check_names_a_wrong_option_with_its_line(magline_station):
    station = magline_station(replace={"products": {"ACME-7": {**ACME_PART, "options": {"boot_timeout": 5.0}}},
                                       "default_part": "ACME-7"})
    problems = check_station(station)
    assert [(p.key, p.message) for p in problems] == [
        ("products.ACME-7.options.boot_timeout", "unknown key (did you mean 'boot_timeout_s'?)")]
    assert problems[0].line > 1


def acme_station(magline_station, board, temp_limit: dict) -> str:
    return magline_station(replace={
        "products": {"ACME-7": {**ACME_PART, "connection": board.connection,
                                "limits": {**ACME_PART["limits"], "acme_board_temp_c": temp_limit}}},
        "default_part": "ACME-7",
        "acquisition": {"samples": 400, "rate_hz": 100.0, "coverage_bins": 40, "coverage_target": 0.6,
                        "retries": 1, "retry_delay_s": 0.0, "timeout_s": 20.0},
        "results": {"sink": "sqlite", "path": "units.sqlite"}})


def test_the_plugin_s_own_measurement_is_limited_judged_and_stored_like_magline_s(board, magline_station, magline_run,
                                                                                  magline_results):
    station = acme_station(magline_station, board, {"le": 60.0})
    assert check_station(station) == []
    record = magline_run(station, "ACME-0002")
    assert record.verdict == "pass", record.cause
    temp = next(m for m in record.measurements if m.name == "acme_board_temp_c")
    assert (temp.value, temp.unit, temp.high, temp.verdict) == (41.5, "°C", 60.0, "pass")
    stored = magline_results(station).run(record.run_id)
    assert any(m["name"] == "acme_board_temp_c" and m["value"] == 41.5 for m in stored["measurements"])


def test_a_board_running_hot_fails_on_the_plugin_s_limit_and_the_limit_set_s_hash_holds_it(board, magline_station,
                                                                                          magline_run):
    board.board_temp_c = 75.0
    failed = magline_run(acme_station(magline_station, board, {"le": 60.0}), "ACME-0003")
    assert failed.verdict == "fail"
    assert "acme_board_temp_c" in failed.cause
    assert failed.params_written == {}  # never written to a unit that failed
    passed = magline_run(acme_station(magline_station, board, {"le": 80.0}), "ACME-0004")
    assert passed.verdict == "pass", passed.cause
    assert passed.limit_hash != failed.limit_hash


def test_a_limit_no_temperature_can_meet_is_refused_by_check_with_its_line(board, magline_station):
    problems = check_station(acme_station(magline_station, board, {"range": [200.0, 400.0]}))
    assert [(p.key, p.message.split(":")[0]) for p in problems] == [
        ("products.ACME-7.limits.acme_board_temp_c", "no value can lie in [200, 400]")]
    assert problems[0].line > 1


def feed_station(magline_station, board, feed: dict) -> str:
    return magline_station(replace={
        "products": {"ACME-7": {**ACME_PART, "connection": board.connection}}, "default_part": "ACME-7",
        "acquisition": {"samples": 400, "rate_hz": 100.0, "coverage_bins": 40, "coverage_target": 0.6,
                        "retries": 1, "retry_delay_s": 0.0, "timeout_s": 20.0},
        "results": {"sink": "sqlite", "path": "units.sqlite"}, "plugins": {"acme-feed": feed}})


def test_the_plant_feed_writes_each_finished_unit_where_the_station_file_says(board, magline_station, magline_run,
                                                                             tmp_path):
    record = magline_run(feed_station(magline_station, board, {"path": "plant/feed.jsonl", "parts": ["ACME-7"]}),
                         "ACME-0005")
    assert record.verdict == "pass", record.cause
    line, = [json.loads(x) for x in (tmp_path / "plant" / "feed.jsonl").read_text().splitlines()]
    assert (line["serial"], line["part"], line["verdict"]) == ("ACME-0005", "ACME-7", "pass")
    assert line["measurements"]["hard_iron_norm_ut"] > 0 and line["limit_hash"] == record.limit_hash


def test_a_feed_that_cannot_write_is_said_on_the_run_and_the_verdict_stands(board, magline_station, magline_run,
                                                                             tmp_path):
    (tmp_path / "plant").write_text("a file where the feed's folder should be")
    record = magline_run(feed_station(magline_station, board, {"path": "plant/feed.jsonl"}), "ACME-0006")
    assert record.verdict == "pass", record.cause
    fault, = record.listener_faults
    assert "acme-feed" in fault and "magline_unit_finished" in fault


def test_check_names_a_wrong_feed_setting_with_its_line(board, magline_station):
    problems = check_station(feed_station(magline_station, board, {"path": "plant/feed.jsonl", "part": "X"}))
    assert [(p.key, p.message) for p in problems] == [
        ("plugins.acme-feed.part", "unknown key (did you mean 'parts'?)")]
    assert problems[0].line > 1


def test_a_stream_asked_again_at_once_sends_each_sample_once_in_order(board):
    """STOP and STREAM in one breath (a station's second attempt): the board's stamps still increase, one
    stream at a time, and nothing streams after ``OK STOP``."""
    import itertools
    import socket
    import time

    time.sleep(max(0.0, board.up_at - time.monotonic()))  # a booting board hangs up on whoever calls
    host, port = board.connection.removeprefix("tcp:").rsplit(":", 1)
    with socket.create_connection((host, int(port)), timeout=10) as client, \
            client.makefile("rw", encoding="ascii", newline="\n") as wire:
        stamps: list[int] = []
        for _ in range(5):
            wire.write("STREAM 100\n")
            wire.flush()
            for _ in range(20):
                line = wire.readline().split()
                if line and line[0] == "M":
                    stamps.append(int(line[1]))
            wire.write("STOP\n")
            wire.flush()
            while (line := wire.readline().split()) and line[0] == "M":
                stamps.append(int(line[1]))
            assert line == ["OK", "STOP"]
        wire.write("ID?\n")
        wire.flush()
        assert wire.readline().split()[0] == "ID"  # not a sample: the stream ended with its STOP
    repeated = [(a, b) for a, b in itertools.pairwise(stamps) if b <= a]
    assert stamps and not repeated, repeated
