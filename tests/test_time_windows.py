"""``--since`` / ``--until`` compare instants (issue 31): every spelling of one instant selects the
same runs, a time without offset is local, what does not parse is refused with exit 2."""

from __future__ import annotations

import time
from datetime import UTC, datetime, timedelta

import pytest

from magline.core.cli import main
from magline.core.results.instants import parse_instant, stored_form
from magline.core.results.sqlite_store import SqliteSink
from magline.testing import make_record


@pytest.fixture
def zurich(monkeypatch):
    """The station PC's clock in Central European Time (UTC+1 in November)."""
    monkeypatch.setenv("TZ", "Europe/Zurich")
    time.tzset()
    yield
    monkeypatch.undo()
    time.tzset()


def test_every_spelling_of_one_instant_is_the_same_instant(zurich):
    spellings = ["2026-11-24T21:53", "2026-11-24 21:53", "2026-11-24T20:53Z", "2026-11-24T21:53+01:00",
                 "2026-11-24T20:53:00+00:00", "2026-11-24T15:53-05:00"]
    instants = {parse_instant(s) for s in spellings}
    assert instants == {datetime(2026, 11, 24, 20, 53, tzinfo=UTC)}
    assert stored_form(parse_instant("2026-11-24")) == "2026-11-23T23:00:00.000+00:00"  # local midnight


def test_relative_forms_count_back_from_now(zurich):
    now = datetime(2026, 11, 25, 10, 0, tzinfo=UTC)  # 11:00 in Zurich
    assert parse_instant("yesterday", now) == datetime(2026, 11, 23, 23, 0, tzinfo=UTC)
    assert parse_instant("today", now) == datetime(2026, 11, 24, 23, 0, tzinfo=UTC)
    assert parse_instant("-8h", now) == parse_instant("8h", now) == now - timedelta(hours=8)
    assert parse_instant("7d", now) == now - timedelta(days=7)
    with pytest.raises(ValueError, match="is not a time: give an ISO 8601 time"):
        parse_instant("last tuesday", now)


def test_export_and_spc_select_the_same_runs_for_every_spelling(make_station, capsys, zurich):
    station = make_station()
    store = SqliteSink(station.parent / "magline-demo-results.sqlite")
    base = datetime(2026, 11, 24, 20, 0, tzinfo=UTC)
    for minutes in range(0, 120, 10):  # 12 runs, 20:00 … 21:50 UTC
        started = stored_form(base + timedelta(minutes=minutes))
        store.finish(make_record(f"T-{minutes:03d}", part="MOCK-100", started=started))
    store.close()

    def exported(since: str) -> list[str]:
        assert main(["export", "--station", str(station), "--since", since]) == 0
        lines = capsys.readouterr().out.strip().splitlines()[1:]
        return [line.split(",")[2] for line in lines]

    expected = exported("2026-11-24T20:53Z")
    assert len(expected) == 6  # 21:00 … 21:50
    for spelling in ("2026-11-24T21:53", "2026-11-24 21:53", "2026-11-24T21:53+01:00"):
        assert exported(spelling) == expected
    with pytest.raises(SystemExit) as refused:  # a usage error, as argparse reports it: exit 2
        main(["export", "--station", str(station), "--since", "2026-11-24T20:53Z", "--until", "21:20"])
    assert refused.value.code == 2 and "is not a time" in capsys.readouterr().err
    assert main(["spc", "--station", str(station), "--since", "yesterday"]) == 2  # these units are older
    assert "nothing to chart" in capsys.readouterr().err
    for command in ("export", "spc"):  # a window that ends before it starts is a usage error, not "0 runs"
        assert main([command, "--station", str(station), "--since", "2026-11-25", "--until", "2026-11-24"]) == 2
        said = capsys.readouterr()
        assert said.out == "" and "is not before --until" in said.err and "swapped?" in said.err


def test_until_a_date_includes_that_day_and_a_verdict_is_taken_in_any_case(make_station, capsys, zurich):
    """Issue 45: ``--until 2026-11-24`` meant its first instant and left the whole day out; a date now
    includes its day (to the next local midnight), a time stays the instant it names.  ``--verdict
    PASS`` is ``pass``."""
    from magline.core.results.instants import until_argument

    assert until_argument("2026-11-24") == "2026-11-24T23:00:00.000+00:00"  # Zurich's midnight after the 24th
    assert until_argument("2026-11-24T12:00Z") == "2026-11-24T12:00:00.000+00:00"
    station = make_station()
    store = SqliteSink(station.parent / "magline-demo-results.sqlite")
    for hour in (8, 22, 23):  # UTC: 09:00 and 23:00 on the 24th in Zurich, 00:00 on the 25th
        store.finish(make_record(f"D-{hour}", part="MOCK-100", verdict="pass",
                                 started=stored_form(datetime(2026, 11, 24, hour, 0, tzinfo=UTC))))
    store.close()
    capsys.readouterr()
    assert main(["export", "--station", str(station), "--until", "2026-11-24", "--verdict", "PASS"]) == 0
    serials = [line.split(",")[2] for line in capsys.readouterr().out.strip().splitlines()[1:]]
    assert serials == ["D-8", "D-22"]
