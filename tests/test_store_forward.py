"""Store-and-forward: the factory network (here: the PostgreSQL server) goes down mid-batch, the
station keeps testing, and every record reaches the server exactly once."""

from __future__ import annotations

import pytest
from sqlalchemy import create_engine, func, select
from sqlalchemy.exc import OperationalError

from magline.core.cli import main
from magline.core.plugins import load_plugins
from magline.core.record import Outcome
from magline.core.results import forwarding
from magline.core.results.tables import attempts, runs
from magline.core.sequencer import Sequencer
from magline.core.station import load_station


@pytest.fixture
def central(postgres, monkeypatch):
    url = postgres.new_database()
    monkeypatch.setenv("MAGLINE_CENTRAL_URL", url)
    yield url
    postgres.start_if_stopped()


def station(make_station):
    return make_station({"results": {"sink": "sql", "url_env": "MAGLINE_CENTRAL_URL", "outbox": "outbox.sqlite"}})


def central_counts(url: str) -> tuple[int, int, int]:
    engine = create_engine(url)
    with engine.connect() as conn:
        n_runs = conn.execute(select(func.count()).select_from(runs)).scalar_one()
        n_uuids = conn.execute(select(func.count(func.distinct(runs.c.run_uuid)))).scalar_one()
        n_attempts = conn.execute(select(func.count()).select_from(attempts)).scalar_one()
    engine.dispose()
    return n_runs, n_uuids, n_attempts


def run_units(path, serials):
    seq = Sequencer(load_station(path), load_plugins(), path.parent, sleep=lambda s: None)
    try:
        return [seq.run_unit(s) for s in serials]
    finally:
        seq.close()


def test_the_server_stopped_mid_batch_loses_nothing_and_duplicates_nothing(make_station, central, postgres, capsys):
    path = station(make_station)
    first = run_units(path, ["F-1", "F-2"])
    assert all(r.verdict is Outcome.PASS and "forwarded" in r.store for r in first)
    assert central_counts(central) == (2, 2, 4)

    postgres.stop()  # the factory network goes down
    down = run_units(path, ["F-3", "F-4"])
    assert all(r.verdict is Outcome.PASS for r in down)  # the station keeps testing
    assert all("QUEUED" in r.store for r in down) and "2 record(s) waiting" in down[-1].store
    assert main(["sync", "--station", str(path)]) == 1  # still down: said, nothing lost
    assert "2 record(s) still queued" in capsys.readouterr().err

    postgres.start_if_stopped()
    assert main(["sync", "--station", str(path)]) == 0
    assert "forwarded 2 record(s)" in capsys.readouterr().out
    assert central_counts(central) == (4, 4, 8)
    assert main(["sync", "--station", str(path)]) == 0  # again: nothing to do, nothing duplicated
    assert "forwarded 0 record(s)" in capsys.readouterr().out
    assert central_counts(central) == (4, 4, 8)


def test_a_forward_interrupted_half_way_leaves_nothing_and_is_retried(make_station, central, monkeypatch, capsys):
    path = station(make_station)
    real = forwarding.copy_children

    def cut_after_the_run_row(source, target, run_id, new_id):
        raise OperationalError("INSERT INTO phases", {}, ConnectionResetError("the network went down half-way"))

    monkeypatch.setattr(forwarding, "copy_children", cut_after_the_run_row)
    (record,) = run_units(path, ["H-1"])
    assert record.verdict is Outcome.PASS and "QUEUED" in record.store and "went down half-way" in record.store
    assert central_counts(central) == (0, 0, 0)  # the run row was rolled back with the rest
    monkeypatch.setattr(forwarding, "copy_children", real)
    assert main(["sync", "--station", str(path)]) == 0
    assert central_counts(central) == (1, 1, 2)


def test_a_run_already_on_the_server_is_not_copied_again(make_station, central):
    """A crash between the server's commit and the outbox's mark: the next forward finds the UUID."""
    path = station(make_station)
    run_units(path, ["D-1"])
    outbox = create_engine(f"sqlite:///{path.parent / 'outbox.sqlite'}")
    with outbox.begin() as conn:
        conn.execute(runs.update().values(forwarded=None))  # as if the mark had never been written
    outbox.dispose()
    assert main(["sync", "--station", str(path)]) == 0
    assert central_counts(central) == (1, 1, 2)
