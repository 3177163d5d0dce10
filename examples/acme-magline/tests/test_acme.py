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
