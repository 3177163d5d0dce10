"""One vehicle, one run (issue 31): a second run on the same vehicle or station slot is refused
before it records anything, naming the holder; the lock goes with the process that held it."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
from pathlib import Path

import pytest
from simstation import FAST_SENSOR_HZ, write_station
from sqlalchemy import create_engine, select

from magline.core.cli import main
from magline.core.plugins import hookimpl, load_plugins
from magline.core.results.tables import runs
from magline.core.sequencer import Sequencer
from magline.core.sequencer.hold import Shared, StationBusy, holder_of, holding, unit_locks
from magline.core.station import load_station
from magline.sim import create_sim

AP = {"connect_timeout_s": 5.0, "boot_timeout_s": 10.0, "prearm_wait_s": 0.3}


def test_a_second_run_on_a_vehicle_under_test_is_refused_naming_the_holder(tmp_path, capsys):
    workdir = tmp_path / "fc"
    workdir.mkdir()
    with create_sim("ardupilot", "tcp:127.0.0.1:0", mag_rate_hz=FAST_SENSOR_HZ, workdir=workdir, seed=2,
                    boot_time_s=0.3, speed=5.0) as sim:
        first_station = write_station("ardupilot-sim.yaml", tmp_path, sim.address, AP)
        (tmp_path / "second").mkdir()
        second_station = write_station("ardupilot-sim.yaml", tmp_path / "second", sim.address, AP,
                                       {"station": {"id": "sim-ardupilot-02"}})
        outcome: dict = {}
        acquiring = threading.Event()

        class Signal:
            @hookimpl
            def magline_acquisition_progress(self, run, attempt, samples, coverage, target):
                acquiring.set()

        def first() -> None:
            seq = Sequencer(load_station(first_station), load_plugins(extra=[Signal()]), tmp_path,
                            sleep=lambda s: None)
            try:
                outcome["record"] = seq.run_unit("PX-DUP-3")
            finally:
                seq.close()

        worker = threading.Thread(target=first)
        worker.start()
        assert acquiring.wait(30)
        assert main(["run", str(second_station), "--serial", "PX-DUP-4"]) == 2
        worker.join(60)
    err = capsys.readouterr().err
    assert f"the vehicle on {sim.address} is busy: station sim-ardupilot-01 is testing serial PX-DUP-3" in err
    assert outcome["record"].verdict == "pass", outcome["record"].cause
    engine = create_engine(f"sqlite:///{tmp_path / 'second' / 'results.sqlite'}")
    with engine.connect() as conn:
        assert conn.execute(select(runs.c.serial)).all() == []  # the refused run recorded nothing
    engine.dispose()


def test_the_same_station_slot_twice_is_refused_and_freed_after(make_station):
    station = load_station(make_station())
    keys = unit_locks(station, ".", station.products["MOCK-100"], None)
    # the station's slot in its store; the mock's in-process link is no shared vehicle
    assert [k.what for k in keys] == ["station demo-01"]
    assert str(Path("magline-demo-results.sqlite").resolve()) in keys[0].key
    with holding(keys, holder_of("SN-1", "demo-01", None)), \
            pytest.raises(StationBusy, match=r"^station demo-01 is busy testing serial SN-1 \("), \
            holding(keys, holder_of("SN-2", "demo-01", None)):
        raise AssertionError("a second holder got the lock")
    with holding(keys, holder_of("SN-2", "demo-01", None)):
        pass  # released when the first run ended


LINK = [Shared("link-tcp:127.0.0.1:9", "the vehicle on tcp:127.0.0.1:9")]


def test_a_lock_dies_with_the_process_that_held_it(tmp_path):
    script = ("import time; from magline.core.sequencer.hold import holding, holder_of, Shared\n"
              "with holding([Shared('link-tcp:127.0.0.1:9', 'the vehicle on tcp:127.0.0.1:9')], "
              "holder_of('SN-9', 'st-9', 'A')):\n"
              "    print('held', flush=True); time.sleep(60)\n")
    child = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout.readline().strip() == "held"
        with pytest.raises(StationBusy) as busy, holding(LINK, holder_of("SN-10", "st-9", "A")):
            raise AssertionError("the vehicle was free while the other process held it")
        assert "the vehicle on tcp:127.0.0.1:9 is busy: station st-9 slot A" in str(busy.value)
        assert f"pid {child.pid}" in str(busy.value)
    finally:
        child.kill()
        child.wait()
    # the operating system released it with the process: no stale lock file blocks the slot
    with holding(LINK, holder_of("SN-10", "st-9", "A")):
        pass


def from_the_next_boot(sim, change) -> None:
    """From its next boot on, the simulator is another board: ``change(sim)`` runs after that boot."""
    boot = sim._boot

    def another_board_boots(now, first=False):
        boot(now, first)
        if not first:
            change(sim)

    sim._boot = another_board_boots


def another_board_after_the_power_cycle(sim, system_id: int) -> None:
    """Another vehicle answers after the power cycle (a cable moved, a second board): another system id."""
    def renumber(s):
        s.system_id = s.mav.srcSystem = system_id

    from_the_next_boot(sim, renumber)


def another_board_with_the_same_system_id(sim) -> None:
    """Another board of the same product answers: the same MAVLink system id, another hardware UID
    (a swapped board, a second unit on the same cable)."""
    def next_uid(s):
        s.uid += 1

    from_the_next_boot(sim, next_uid)


@pytest.mark.parametrize("flavour", ["ardupilot", "px4"])
def test_another_board_with_the_same_system_id_is_found_by_its_uid(tmp_path, flavour):
    """Issue 31: boards of one product share a system id; the hardware UID tells them apart."""
    workdir = tmp_path / "fc"
    workdir.mkdir()
    listen = "tcp:127.0.0.1:0" if flavour == "ardupilot" else "udp:127.0.0.1:0"
    with create_sim(flavour, listen, mag_rate_hz=FAST_SENSOR_HZ, workdir=workdir, seed=2, boot_time_s=0.3,
                    speed=5.0) as sim:
        uid = sim.uid
        another_board_with_the_same_system_id(sim)
        if flavour == "ardupilot":
            station = write_station("ardupilot-sim.yaml", tmp_path, sim.address, AP)
        else:
            host, port = sim.address.split(":")[1:]
            station = write_station("px4-sim.yaml", tmp_path, f"udpout://{host}:{port}",
                                    {"connect_timeout_s": 5.0, "boot_timeout_s": 10.0, "save_settle_s": 0.1})
        seq = Sequencer(load_station(station), load_plugins(), tmp_path, sleep=lambda s: None)
        try:
            record = seq.run_unit("UID-SWAP")
        finally:
            seq.close()
    assert record.verdict == "error", record.cause
    assert f"reports hardware UID {uid + 1:#x}, not the unit under test's ({uid:#x})" in record.cause


def test_another_vehicle_answering_after_the_power_cycle_is_an_error_not_a_verdict(tmp_path):
    workdir = tmp_path / "fc"
    workdir.mkdir()
    with create_sim("ardupilot", "tcp:127.0.0.1:0", mag_rate_hz=FAST_SENSOR_HZ, workdir=workdir, seed=2,
                    boot_time_s=0.3, speed=5.0) as sim:

        another_board_after_the_power_cycle(sim, 7)
        station = write_station("ardupilot-sim.yaml", tmp_path, sim.address, AP)
        seq = Sequencer(load_station(station), load_plugins(), tmp_path, sleep=lambda s: None)
        try:
            record = seq.run_unit("SN-SWAP")
        finally:
            seq.close()
    assert record.verdict == "error", record.cause
    assert "MAVLink system id 7 answered" in record.cause and "not the unit under test (system id 1)" in record.cause


def test_another_px4_answering_after_the_power_cycle_is_an_error_not_a_verdict(tmp_path):
    workdir = tmp_path / "fc"
    workdir.mkdir()
    with create_sim("px4", "udp:127.0.0.1:0", mag_rate_hz=FAST_SENSOR_HZ, workdir=workdir, seed=2,
                    boot_time_s=0.3, speed=5.0) as sim:
        another_board_after_the_power_cycle(sim, 9)
        host, port = sim.address.split(":")[1:]
        station = write_station("px4-sim.yaml", tmp_path, f"udpout://{host}:{port}",
                                {"connect_timeout_s": 5.0, "boot_timeout_s": 10.0, "save_settle_s": 0.1})
        seq = Sequencer(load_station(station), load_plugins(), tmp_path, sleep=lambda s: None)
        try:
            record = seq.run_unit("PX-SWAP")
        finally:
            seq.close()
    assert record.verdict == "error", record.cause
    assert "MAVLink system id 9 answered" in record.cause


def test_a_second_computer_on_the_same_station_slot_is_refused_by_the_results_server(
        make_station, postgres, monkeypatch, tmp_path, capsys):
    """Issue 31: two PCs given one station file share only the results server. While PC 1 tests a unit,
    PC 2 (its own file locks, its own host name) is refused before it records anything, naming PC 1's
    run; ``magline slots`` shows the holder; once PC 1 is done the slot is free again."""
    import types

    from magline.core.sequencer import hold

    monkeypatch.setenv("MAGLINE_CENTRAL_URL", postgres.new_database())
    path = make_station({"results": {"sink": "sql", "url_env": "MAGLINE_CENTRAL_URL", "outbox": "outbox.sqlite"}})
    acquiring, finish = threading.Event(), threading.Event()

    class HoldTheTumble:
        @hookimpl
        def magline_acquisition_progress(self, run, attempt, samples, coverage, target):
            acquiring.set()
            finish.wait(30)

    first = Sequencer(load_station(path), load_plugins(extra=[HoldTheTumble()]), path.parent, sleep=lambda s: None)
    results: list = []
    worker = threading.Thread(target=lambda: results.append(first.run_unit("PC1-UNIT")))
    worker.start()
    try:
        assert acquiring.wait(30)
        assert main(["slots", "--station", str(path)]) == 0
        assert "station demo-01: serial PC1-UNIT on " in capsys.readouterr().out
        # the second computer: its own lock folder and host name, the same server
        monkeypatch.setenv("MAGLINE_LOCK_DIR", str(tmp_path / "pc2-locks"))
        monkeypatch.setattr(hold, "socket", types.SimpleNamespace(gethostname=lambda: "line-pc-2"))
        second = Sequencer(load_station(path), load_plugins(), tmp_path, sleep=lambda s: None)
        try:
            with pytest.raises(StationBusy, match=r"station demo-01 is testing serial PC1-UNIT on .* \(pid \d+"):
                second.run_unit("PC2-UNIT")
        finally:
            second.close()
    finally:
        finish.set()
        worker.join(60)
        first.close()
    assert results and results[0].verdict.value == "pass", results
    engine = create_engine(os.environ["MAGLINE_CENTRAL_URL"])
    with engine.connect() as conn:
        assert [r.serial for r in conn.execute(select(runs.c.serial))] == ["PC1-UNIT"]  # nothing of PC 2
    engine.dispose()
    second = Sequencer(load_station(path), load_plugins(), tmp_path, sleep=lambda s: None)
    try:
        assert second.run_unit("PC2-UNIT").verdict.value == "pass"  # PC 1 gave the slot back
    finally:
        second.close()
    assert main(["slots", "--station", str(path)]) == 0 and "no slot is held" in capsys.readouterr().out
