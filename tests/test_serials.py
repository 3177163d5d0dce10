"""Clean serials (issue 31): trimmed, refused before a record exists when empty, holding a control
character or a path separator, too long or not matching the part's pattern; found whatever spaces
surround them in the reading commands."""

from __future__ import annotations

import re

import pytest
from sqlalchemy import create_engine, func, select

from magline.core.cli import main
from magline.core.results.tables import runs
from magline.core.serials import SerialRefused, clean_serial
from magline.core.station import load_station
from magline.testing import check_station


@pytest.mark.parametrize(("typed", "rule"), [
    ("", "no serial number"), ("   ", "no serial number"), ("SN\n2", "control character U+000A"),
    ("SN\x07", "control character U+0007"), ("SN\t1", "control character U+0009"), ("LINE/7", "SOLIDUS"),
    ("X" * 300, "at most 64"),
])
def test_a_serial_that_breaks_a_rule_is_refused_with_the_rule(typed, rule):
    with pytest.raises(SerialRefused, match=re.escape(rule)):
        clean_serial(typed)


def test_surrounding_spaces_are_trimmed_and_the_parts_pattern_and_length_apply(make_station):
    assert clean_serial("  SN-TRIM \r\n".strip("\r\n") + " ") == "SN-TRIM"
    product = load_station(make_station({"products": {"MOCK-100": {
        "serial_pattern": r"MK-\d{6}", "serial_max_length": 9}}})).products["MOCK-100"]
    assert clean_serial(" MK-000123", product) == "MK-000123"
    with pytest.raises(SerialRefused, match=r"does not match this part's pattern MK-\\d\{6\}"):
        clean_serial("MK-12A456", product)
    with pytest.raises(SerialRefused, match="at most 9"):
        clean_serial("MK-0001234", product)


def test_magline_check_names_a_pattern_that_is_no_regular_expression(make_station):
    path = make_station({"products": {"MOCK-100": {"serial_pattern": "MK-(\\d+"}}})
    problems = check_station(path)
    assert [p.key for p in problems] == ["products.MOCK-100.serial_pattern"]
    assert "not a regular expression" in problems[0].message and problems[0].line > 0


def _runs(station) -> list[str]:
    engine = create_engine(f"sqlite:///{station.parent / 'magline-demo-results.sqlite'}")
    try:
        with engine.connect() as conn:
            return [r.serial for r in conn.execute(select(runs.c.serial))]
    finally:
        engine.dispose()


def test_run_stores_the_trimmed_serial_and_refuses_bad_ones_before_any_record(make_station, capsys):
    station = make_station()
    assert main(["run", str(station), "--serial", "  SN-TRIM  "]) == 0
    for bad in ("", "A\nB", "SN/7"):
        assert main(["run", str(station), "--serial", bad]) == 2
    assert _runs(station) == ["SN-TRIM"]  # no record for any refused serial
    err = capsys.readouterr().err
    assert "no serial number" in err and "control character U+000A" in err
    assert main(["history", " SN-TRIM ", "--station", str(station)]) == 0
    assert "#1 " in capsys.readouterr().out  # the unit's run, found with the spaces typed around its serial


def test_a_loop_refuses_a_bad_scan_and_takes_the_next(make_station, monkeypatch, capsys):
    station = make_station()
    scans = iter(["GOOD-1", "BAD\tSCAN", "GOOD-2", ""])
    monkeypatch.setattr("builtins.input", lambda prompt="": next(scans))
    assert main(["run", str(station), "--loop"]) == 0
    assert _runs(station) == ["GOOD-1", "GOOD-2"]
    assert "control character U+0009" in capsys.readouterr().err


def test_a_serial_refused_by_the_sequencer_leaves_no_record(make_station):
    from magline.core.plugins import load_plugins
    from magline.core.sequencer import Sequencer

    path = make_station()
    seq = Sequencer(load_station(path), load_plugins(), path.parent, sleep=lambda s: None)
    try:
        with pytest.raises(SerialRefused):
            seq.run_unit("\x1b[31mRED")
    finally:
        seq.close()
    engine = create_engine(f"sqlite:///{path.parent / 'magline-demo-results.sqlite'}")
    with engine.connect() as conn:
        assert conn.execute(select(func.count()).select_from(runs)).scalar() == 0
    engine.dispose()
