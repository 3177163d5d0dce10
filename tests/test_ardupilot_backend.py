"""The ArduPilot backend end to end against the simulated ArduPilot over TCP on loopback."""

from __future__ import annotations

import json
import sqlite3
from types import SimpleNamespace

import numpy as np
import pytest
from simstation import FAST_SENSOR_HZ, load_json, run_unit, stored_attempts, write_station

from magline.core.record import Outcome
from magline.plugins.ardupilot.calibration import HeldCalibration, fit_to_params
from magline.sim import SimFaults, create_sim

OPTIONS = {"connect_timeout_s": 5.0, "boot_timeout_s": 10.0, "prearm_wait_s": 0.3}


def start_sim(tmp_path, mags: int = 1, faults: SimFaults | None = None, stored: dict | None = None):
    workdir = tmp_path / "fc"
    workdir.mkdir()
    if stored:
        (workdir / "eeprom.json").write_text(__import__("json").dumps(stored), encoding="utf-8")
    return create_sim("ardupilot", "tcp:127.0.0.1:0", mag_rate_hz=FAST_SENSOR_HZ,
                      workdir=workdir, mag_count=mags, seed=11,
                      boot_time_s=0.3, speed=5.0, faults=faults).start()


def test_units_and_sign_convention_at_the_plugin_boundary():
    fit = SimpleNamespace(hard_iron_ut=np.array([1.0, -2.0, 30.0]),
                          soft_iron=np.array([[1.1, 0.01, 0.02], [0.01, 0.9, 0.03], [0.02, 0.03, 1.0]]))
    params = fit_to_params(fit, "2")
    assert [params[f"COMPASS_OFS2_{a}"] for a in "XYZ"] == pytest.approx([-10.0, 20.0, -300.0])  # mG, added
    assert [params[f"COMPASS_DIA2_{a}"] for a in "XYZ"] == pytest.approx([1.1, 0.9, 1.0])
    assert [params[f"COMPASS_ODI2_{a}"] for a in "XYZ"] == pytest.approx([0.01, 0.02, 0.03])
    assert params["COMPASS_SCALE2"] == 1.0


def test_inverse_correction_matches_the_simulated_firmware(tmp_path, rng):
    """The backend undoes exactly what the (independently written) simulator applies."""
    with start_sim(tmp_path) as sim:
        for scale in (0.0, 1.2, 2.0):  # 2.0 is outside [1/1.5, 1.5]: the firmware ignores it
            values = {"COMPASS_OFS_X": 120.0, "COMPASS_OFS_Y": -40.0, "COMPASS_OFS_Z": 300.0,
                      "COMPASS_DIA_X": 1.05, "COMPASS_DIA_Y": 0.97, "COMPASS_DIA_Z": 1.01,
                      "COMPASS_ODI_X": 0.02, "COMPASS_ODI_Y": -0.01, "COMPASS_ODI_Z": 0.03, "COMPASS_SCALE": scale}
            for name, value in values.items():
                sim.table.set(name, value)
            raw_mg = rng.normal(scale=400, size=(20, 3))
            corrected = np.array([sim.correct_mg(0, r) for r in raw_mg])
            held = HeldCalibration.from_params(values, "")
            assert held.raw_ut(corrected) == pytest.approx(raw_mg / 10.0, abs=1e-3)


def test_end_to_end_pass_writes_the_fit_and_it_survives_the_reboot(tmp_path):
    # the firmware's calibrated output is checked to 1 % in whatever attitude the unit rests after the
    # reboot: that needs the whole tumble's calibration (a determined tumble is as good as the station's
    # limits ask, 3 % by default, and its partial coverage once read 48.5 µT there)
    with start_sim(tmp_path) as sim:
        record = run_unit(write_station("ardupilot-sim.yaml", tmp_path, sim.address, OPTIONS,
                                        {"acquisition": {"stop": "samples"}}))
        assert record.verdict is Outcome.PASS, record.cause
        h = np.array(record.calibration["hard_iron_ut"])
        s = np.array(record.calibration["soft_iron"])
        stored = load_json(sim.storage_path)
        assert [stored[f"COMPASS_OFS_{a}"] for a in "XYZ"] == pytest.approx(-10 * h, abs=1e-4, rel=1e-6)
        assert [stored[f"COMPASS_DIA_{a}"] for a in "XYZ"] == pytest.approx(np.diag(s), abs=1e-4)
        assert [stored[f"COMPASS_ODI_{a}"] for a in "XYZ"] == pytest.approx([s[0, 1], s[0, 2], s[1, 2]], abs=1e-4)
        assert stored["COMPASS_DEV_ID"] == sim.magnetometers[0].device_id  # force-saved
        assert sim.boots == 2  # it really rebooted
        radius = np.linalg.norm(sim.corrected_sphere(sim.magnetometers[0].device_id), axis=1)
        assert abs(radius.mean() - sim.field_ut) < 0.3 and radius.std() < 0.6  # a sphere within the noise
        assert np.linalg.norm(h - sim.magnetometers[0].hard_iron_ut) < 1.0
        # each reading is the mean of the driver's samples since the vehicle last read the compass (here 100 times
        # a second, as often as its driver samples): each reading is one sample, and the fit leaves it as it is
        assert record.calibration["reading_window"]["window_s"] == pytest.approx(1.0 / FAST_SENSOR_HZ, rel=0.05)
        assert record.calibration["reading_window"]["samples"] == 1  # read as often as its driver samples: no mean
        assert record.calibration["reading_window"]["correction_max_ut"] == 0.0
        assert record.params_before["COMPASS_OFS_X"] == 0.0
        assert record.params_read_back == pytest.approx(record.params_written, rel=1e-6, abs=1e-4)
        assert record.persistence["method"] == "link-reboot"
        assert record.persistence["figures"]["time_to_heartbeat_s"] > 0
        # proven on the firmware's own terms: its corrected stream reads the reference field
        assert record.persistence["figures"]["calibrated_field_ut"] == pytest.approx(48.0, rel=0.01)


def test_three_compasses_with_reordered_priorities_calibrates_the_named_one(tmp_path):
    # the other two compasses are not used for navigation here (else ArduPilot's arming check would,
    # rightly, fail the unit for them: a line calibrates every compass it uses)
    with start_sim(tmp_path, mags=3, stored={"COMPASS_PRIO1_ID": 4395033, "COMPASS_PRIO2_ID": 396809,
                                             "COMPASS_PRIO3_ID": 458786, "COMPASS_USE": 0,
                                             "COMPASS_USE3": 0}) as sim:
        target = sim.sensor(396809)
        assert sim.sets.index(target) == 1  # the named sensor sits in set 2 after the boot reorder
        record = run_unit(write_station("ardupilot-sim.yaml", tmp_path, sim.address, OPTIONS,
                                        {"products": {"AP-QUAD-200": {"magnetometer": 396809}}}))
        assert record.verdict is Outcome.PASS, record.cause
        assert record.unit_info["compass_set"] == 2
        stored = load_json(sim.storage_path)
        assert stored["COMPASS_OFS2_X"] == pytest.approx(-10 * record.calibration["hard_iron_ut"][0], rel=1e-6)
        assert not any(k.startswith(("COMPASS_OFS_", "COMPASS_OFS3_", "COMPASS_DIA_", "COMPASS_DIA3_"))
                       for k in stored)  # the other sets untouched
        assert np.linalg.norm(np.array(record.calibration["hard_iron_ut"]) - target.hard_iron_ut) < 1.0


def test_a_magnetometer_the_unit_does_not_have_fails_with_the_ids_it_has(tmp_path):
    with start_sim(tmp_path, mags=2) as sim:
        record = run_unit(write_station("ardupilot-sim.yaml", tmp_path, sim.address, OPTIONS,
                                        {"products": {"AP-QUAD-200": {"magnetometer": 12345}}}))
        assert record.verdict is Outcome.FAIL
        assert "magnetometer 12345 is not on this unit; it has 396809, 458786" in record.cause


def test_dev_id_trap_is_caught_by_verify_when_the_force_save_is_disabled(tmp_path):
    with start_sim(tmp_path) as sim:
        record = run_unit(write_station("ardupilot-sim.yaml", tmp_path, sim.address,
                                        {**OPTIONS, "force_save_device_ids": False}))
        assert record.verdict is Outcome.FAIL
        assert [p.name for p in record.phases if p.outcome is Outcome.FAIL] == ["verify"]
        assert "PreArm: Compass not calibrated" in record.cause


def test_ignored_parameter_fails_the_unit_and_rolls_back(tmp_path):
    with start_sim(tmp_path, faults=SimFaults(ignore_param_set=["COMPASS_ODI_Y"])) as sim:
        record = run_unit(write_station("ardupilot-sim.yaml", tmp_path, sim.address, OPTIONS), "SN-ODI")
        assert record.verdict is Outcome.FAIL
        assert "COMPASS_ODI_Y" in record.cause and "no echo" in record.cause
        assert "and COMPASS_ODI_Y still reads 0: the autopilot ignored the write" in record.cause  # proven by a read
        assert "previous values restored" in record.cause
        stored = load_json(sim.storage_path)
        assert not any(k.startswith(("COMPASS_OFS_", "COMPASS_DIA_")) for k in stored)  # nothing half-written
        kept = stored_attempts(tmp_path / "results.sqlite", "SN-ODI")[0][0]
        assert kept == record.attempts[0].samples > 0  # raw data kept


def test_a_write_whose_echoes_are_lost_is_proven_by_a_read_and_the_unit_passes(tmp_path):
    """No echo is not a refusal: on a lossy link the write may have taken and only its echoes been lost
    (what failed one good unit in 200 of the benchmark's lossy row).  The station reads the parameter
    back; it holds the value written, so the unit passes."""
    with start_sim(tmp_path, faults=SimFaults(lose_param_echo=["COMPASS_DIA_X"])) as sim:
        record = run_unit(write_station("ardupilot-sim.yaml", tmp_path, sim.address, OPTIONS), "SN-ECHO")
        assert record.verdict is Outcome.PASS, record.cause
        assert record.params_read_back["COMPASS_DIA_X"] == pytest.approx(record.params_written["COMPASS_DIA_X"])
        assert load_json(sim.storage_path)["COMPASS_DIA_X"] == pytest.approx(record.params_written["COMPASS_DIA_X"])


def test_a_parameter_this_firmware_does_not_have_fails_the_unit_naming_it(tmp_path):
    """ArduPilot answers an unknown name with silence, as a link that loses the answers does; but it
    answers reads in the order they came, so a read sent after each request for the name, answered
    while the name is not, proves the name unknown: the unit's firmware cannot hold its calibration
    (FAIL, the parameter named), and nothing is written to it."""
    with start_sim(tmp_path, faults=SimFaults(unknown_params=["COMPASS_ODI_Y"])) as sim:
        record = run_unit(write_station("ardupilot-sim.yaml", tmp_path, sim.address, OPTIONS), "SN-OLD")
        assert record.verdict is Outcome.FAIL, record.cause
        assert ("this firmware has no parameter COMPASS_ODI_Y: 5 reads of it went unanswered while the reads sent "
                "after each were answered") in record.cause
        assert not sim.storage_path.exists()  # nothing was written to the unit
        # one read, then five each followed by a read by index: told after one wait, not five (15 s)
        assert sim.param_reads["COMPASS_ODI_Y"] == 6


def test_a_read_whose_answers_are_lost_is_asked_until_answered_never_taken_for_an_unknown_name(tmp_path):
    """The proof that a name is unknown is a read sent after it and answered; a name whose answers are
    lost three times is answered at its fourth read, before enough proofs are in.  An unknown name read
    twice is told twice, each by its own reads' answers (a late answer to the first is not the second's)."""
    from magline.plugins.ardupilot.link import ArduPilotLink, NotKnown

    faults = SimFaults(lose_param_answers=["COMPASS_OFFS_MAX:3"], unknown_params=["COMPASS_MOT_X"])
    with start_sim(tmp_path, faults=faults, stored={"COMPASS_OFFS_MAX": 1200}) as sim:
        link = ArduPilotLink(sim.address)
        link.open(5.0)
        try:
            assert link.get("COMPASS_DEV_ID") > 0
            assert link.get("COMPASS_OFFS_MAX") == 1200
            for _ in range(2):
                with pytest.raises(NotKnown, match="this firmware has no parameter COMPASS_MOT_X: 5 reads"):
                    link.get("COMPASS_MOT_X")
            assert link.get("COMPASS_OFFS_MAX") == 1200
        finally:
            link.close()
    # one unanswered, a round of five sent at once (its fourth answered: the value, not a proof), one more
    assert sim.param_reads["COMPASS_OFFS_MAX"] == 7
    assert sim.param_reads["COMPASS_MOT_X"] == 12


def test_a_link_lost_in_the_middle_of_the_write_is_an_error_that_says_to_quarantine_the_unit(tmp_path):
    """The cable is pulled while the calibration is written: the station could not judge the unit (ERROR,
    it was FAIL), the parameters before the loss may be on it, and the rollback is not tried parameter by
    parameter on a silent link: the cause says to quarantine the unit."""
    with start_sim(tmp_path, faults=SimFaults(link_loss_at_param_set="COMPASS_DIA_Y")) as sim:
        record = run_unit(write_station("ardupilot-sim.yaml", tmp_path, sim.address, OPTIONS), "SN-PULL")
        assert record.verdict is Outcome.ERROR, record.cause
        assert "link to" in record.cause and "lost" in record.cause
        assert "ROLLBACK FAILED for" in record.cause and "quarantine it" in record.cause
        persist = next(p for p in record.phases if p.name == "persist")
        # one wait for the silent link, not one per parameter (about 20 of them, 3 s each)
        assert any(line.startswith("rollback stopped: link to ") for line in persist.log), persist.log


def test_lost_link_mid_acquisition_is_an_error_keeps_the_raw_data_and_says_what_is_left_changed(tmp_path):
    """A link that dies is the station's problem (ERROR, not FAIL); COMPASS_LEARN, switched off for
    the test, cannot be put back: the record and the cause say so and name the real cause."""
    with start_sim(tmp_path, faults=SimFaults(link_loss_after_s=0.6), stored={"COMPASS_LEARN": 3}) as sim:
        record = run_unit(write_station("ardupilot-sim.yaml", tmp_path, sim.address,
                                        {**OPTIONS, "stream_timeout_s": 0.5}), "SN-LINK")
        assert record.verdict is Outcome.ERROR
        assert "link lost during acquisition" in record.cause and "raw data kept" in record.cause
        assert record.left_changed == {"COMPASS_LEARN": "0 (was 3)"}
        assert "COMPASS_LEARN left at 0 (was 3); re-test the unit" in record.cause
        assert "PARAM_SET" not in record.cause  # the cause is the link, not a refused write
        (samples, raw), = stored_attempts(tmp_path / "results.sqlite", "SN-LINK")
        assert samples > 10 and len(raw) == samples
        assert not any(k.startswith("COMPASS_OFS") for k in load_json(sim.storage_path))
        with sqlite3.connect(tmp_path / "results.sqlite") as db:
            (verdict, left), = db.execute("SELECT verdict, left_changed FROM runs WHERE serial='SN-LINK'")
        assert verdict == "error" and json.loads(left) == {"COMPASS_LEARN": "0 (was 3)"}


def test_missing_compass_after_reboot_fails_the_unit(tmp_path):
    with start_sim(tmp_path, faults=SimFaults(mag_missing_after_reboot=396809)) as sim:
        record = run_unit(write_station("ardupilot-sim.yaml", tmp_path, sim.address, OPTIONS), "SN-GONE")
        assert record.verdict is Outcome.FAIL
        assert "magnetometer 396809 missing after power cycle" in record.cause
        assert stored_attempts(tmp_path / "results.sqlite", "SN-GONE")


def test_offsets_beyond_compass_offs_max_are_refused_before_writing(tmp_path):
    with start_sim(tmp_path, stored={"COMPASS_OFFS_MAX": 200}) as sim:
        record = run_unit(write_station("ardupilot-sim.yaml", tmp_path, sim.address, OPTIONS))
        assert record.verdict is Outcome.FAIL
        assert "exceeds COMPASS_OFFS_MAX = 200 mG" in record.cause
        assert set(load_json(sim.storage_path)) == {"COMPASS_OFFS_MAX"}  # nothing written


def test_compass_learn_is_switched_off_during_the_test_and_restored(tmp_path):
    with start_sim(tmp_path, stored={"COMPASS_LEARN": 3}) as sim:
        seen: list[int] = []
        from magline.core.plugins import hookimpl, load_plugins
        from magline.core.sequencer import Sequencer
        from magline.core.station import load_station

        class Spy:
            @hookimpl
            def magline_phase_started(self, run, phase):
                if phase == "fit":
                    seen.append(sim.param("COMPASS_LEARN"))

        station = write_station("ardupilot-sim.yaml", tmp_path, sim.address, OPTIONS)
        seq = Sequencer(load_station(station), load_plugins(extra=[Spy()]), tmp_path, sleep=lambda s: None)
        record = seq.run_unit("SN-LEARN")
        seq.close()
        assert record.verdict is Outcome.PASS, record.cause
        assert seen == [0] and sim.param("COMPASS_LEARN") == 3


def test_firmware_limits_name_the_limit_before_anything_is_written():
    from magline.core.dut import DutError
    from magline.plugins.ardupilot.calibration import check_firmware_limits

    good = {"COMPASS_OFS2_X": -300.0, "COMPASS_OFS2_Y": 100.0, "COMPASS_OFS2_Z": 50.0,
            "COMPASS_DIA2_X": 1.0, "COMPASS_DIA2_Y": 1.1, "COMPASS_DIA2_Z": 0.9,
            "COMPASS_ODI2_X": 0.05, "COMPASS_ODI2_Y": -0.02, "COMPASS_ODI2_Z": 0.0, "COMPASS_SCALE2": 1.0}
    check_firmware_limits(good, "2", 1800.0)
    with pytest.raises(DutError, match=r"COMPASS_DIA2_Y = 5.5000 outside ArduPilot's diagonal limits 0.2–5"):
        check_firmware_limits(good | {"COMPASS_DIA2_Y": 5.5}, "2", 1800.0)
    with pytest.raises(DutError, match=r"COMPASS_ODI2_X = 1.2000 outside ArduPilot's off-diagonal limit ±1"):
        check_firmware_limits(good | {"COMPASS_ODI2_X": 1.2}, "2", 1800.0)
    with pytest.raises(DutError, match=r"exceeds COMPASS_OFFS_MAX = 300 mG"):
        check_firmware_limits(good, "2", 300.0)


def test_a_tiny_value_written_after_its_vector_sibling_is_not_confirmed_by_the_sibling_s_stale_echo(tmp_path):
    """ArduPilot echoes every axis of a COMPASS_ vector when one is written, so writing ODI_X puts an
    echo of ODI_Y's *old* value (0) in the queue before ODI_Y is written.  A near-diagonal soft iron
    writes ODI_Y ≈ −4e-7: the link took that stale 0 as its echo (equal "within 1e-6"), and the
    persist check (within 1e-7) then refused a write that had taken — a good unit FAILed (1 board in 8
    of benchmarks/interference.py).  A float parameter is its float32, compared exactly."""
    from magline.plugins.ardupilot.link import ArduPilotLink

    tiny = -4.008063505273429e-07
    with start_sim(tmp_path) as sim:
        real = sim.handle_param_set

        def late_sibling_echo(msg):
            # the X write's echo of ODI_Y's old value still on its way when ODI_Y is written: it arrives
            # after the station drained its queue and before the new echo (the race the benchmark met)
            if msg.param_id == "COMPASS_ODI_Y":
                sim.send_param("COMPASS_ODI_Y")
            real(msg)

        sim.handle_param_set = late_sibling_echo
        link = ArduPilotLink(sim.address)
        link.open(5.0)
        try:
            link.set("COMPASS_ODI_X", 0.0125)
            echoed = link.set("COMPASS_ODI_Y", tiny)
        finally:
            link.close()
        assert echoed == float(np.float32(tiny)) and sim.param("COMPASS_ODI_Y") == pytest.approx(tiny)


def test_a_float_parameter_equals_its_float32_and_nothing_else():
    from magline.core.dut import float32_equal, param_equal

    assert float32_equal(1.05, 1.0499999523162842) and param_equal(1.05, 1.0499999523162842)
    assert not float32_equal(-4.008e-07, 0.0) and not param_equal(-4.008e-07, 0.0)
    assert not float32_equal(1.0, 1.0000002) and param_equal(7, 7.0) and not param_equal(7, 7.5)


def test_a_compass_that_reads_the_same_at_rest_is_proven_with_what_it_reads(tmp_path):
    """At rest after the power cycle every compass reads the same value in every message (a quiet sensor
    whose steps are coarser than its noise; ArduPilot's own SITL compass, which has no noise): no new
    distinct reading comes however long the station waits — it waited for ever, seen on ArduCopter SITL.
    After a bounded wait the repeats are what the compass reads, and the proof holds them to the reference."""
    import threading

    done: dict = {}
    with start_sim(tmp_path, faults=SimFaults(quiet_at_rest=True)) as sim:
        path = write_station("ardupilot-sim.yaml", tmp_path, sim.address, OPTIONS)
        worker = threading.Thread(target=lambda: done.setdefault("record", run_unit(path)), daemon=True)
        worker.start()
        worker.join(300.0)  # far beyond a unit's time: only a station that waits for ever is still running
        assert "record" in done, "the station still waits for a new reading from a compass at rest"
        assert sim.resting is not None  # the proof read a unit lying still
    record = done["record"]
    assert record.verdict is Outcome.PASS, record.cause
    assert record.persistence["figures"]["calibrated_field_ut"] == pytest.approx(sim.field_ut, rel=0.03)
