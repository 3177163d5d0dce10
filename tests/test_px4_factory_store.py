"""PX4's factory calibration store (issue 63): ``persist: factory-storage`` has the commander's gyro
calibration copy the station's CAL_MAGn_* into ``/fs/mtd_caldata``, which a board loads at boot under
the user's parameters — so a customer's reset to defaults brings the factory calibration back.  The
simulated PX4 keeps that store as PX4 does; each failure of the route is an ERROR naming the firmware's
words, with the parameters still proven, or a FAIL where the unit's store does not hold what was
written."""

from __future__ import annotations

from pathlib import Path

import pytest
from simstation import FAST_SENSOR_HZ, run_unit, write_station

from magline.core.record import Outcome
from magline.sim import SimFaults, create_sim
from magline.testing import check_station

PX4_OPTIONS = {"connect_timeout_s": 5.0, "boot_timeout_s": 10.0, "save_settle_s": 0.1}
PART = "PX4-X500-100"


def px4(tmp_path: Path, faults: SimFaults | None = None):
    workdir = tmp_path / "fc"
    workdir.mkdir(parents=True, exist_ok=True)
    return create_sim("px4", "udp:127.0.0.1:0", mag_rate_hz=FAST_SENSOR_HZ, workdir=workdir, seed=5,
                      boot_time_s=0.3, speed=5.0, faults=faults)


def station(tmp_path: Path, sim, **product) -> Path:
    host, port = sim.address.split(":")[1:]
    return write_station("px4-sim.yaml", tmp_path, f"udpout://{host}:{port}", PX4_OPTIONS,
                         {"products": {PART: {"persist": "factory-storage", **product}}})


def rebooted(sim, timeout_s: float = 5.0) -> None:
    """Reboot the simulated board and wait for its new boot."""
    import time

    boots = sim.boots
    sim.request_reboot(0.05)
    deadline = time.monotonic() + timeout_s
    while sim.boots == boots:
        assert time.monotonic() < deadline, "the board did not boot again"
        time.sleep(0.02)


def calibration(values: dict) -> dict:
    return {n: v for n, v in values.items() if n.startswith("CAL_MAG0_") and not n.endswith("_PRIO")}


def test_the_calibration_goes_into_the_factory_store_and_a_reset_to_defaults_brings_it_back(tmp_path):
    with px4(tmp_path) as sim:
        record = run_unit(station(tmp_path, sim))
        written = calibration(record.params_written)
        store = sim.factory_store()
        user_file = sim.read_storage()
        # a customer's ground station resets every parameter to its default, and the board reboots
        sim.write_storage({})
        rebooted(sim)
        after_reset = {n: sim.table.values[n] for n in written}
    assert record.verdict is Outcome.PASS, record.cause
    assert written and all(store[n] == pytest.approx(v, rel=1e-6) for n, v in written.items())
    assert not any(n.endswith("_PRIO") or n == "CAL_MAG_SIDES" for n in store)
    assert user_file.get("SYS_FAC_CAL_MODE", 0) == 0  # left as the product says (0), and saved
    assert after_reset == pytest.approx(written, rel=1e-6)
    kept = record.persistence["store"]
    assert kept.startswith("factory calibration store, written ([cal] calibration done: gyro)")
    assert "read back equal" in kept and "SYS_FAC_CAL_MODE left at 0" in kept


def test_the_store_is_proven_by_a_calibration_reset_when_the_product_asks(tmp_path):
    with px4(tmp_path) as sim:
        record = run_unit(station(tmp_path, sim, prove_factory_restore=True, factory_cal_mode_after=2))
        boots = sim.boots
        mode = sim.table.values["SYS_FAC_CAL_MODE"]
    assert record.verdict is Outcome.PASS, record.cause
    assert boots == 3  # the power cycle, then the reset's reboot
    assert mode == 2
    assert "given back after a calibration reset and a reboot" in record.persistence["store"]


def test_a_board_without_the_partition_is_an_error_naming_it_with_its_parameters_proven(tmp_path):
    with px4(tmp_path, SimFaults(no_factory_partition=True)) as sim:
        record = run_unit(station(tmp_path, sim))
    assert record.verdict is Outcome.ERROR
    assert "ERROR: cannot open calibration storage" in record.cause and "proven as ordinary parameters" in record.cause
    # the parameters did survive the power cycle (read back as the float32 PX4 holds)
    assert record.params_read_back == pytest.approx(record.params_written, rel=1e-6)
    assert record.persistence["store"].startswith("parameters only — the factory store was NOT written")


def test_a_unit_moved_during_the_gyro_calibration_is_an_error_quoting_the_firmware(tmp_path):
    with px4(tmp_path, SimFaults(moved_during_gyro_cal=True)) as sim:
        record = run_unit(station(tmp_path, sim))
        store = sim.factory_store()
    assert record.verdict is Outcome.ERROR
    assert "ERROR: Motion during calibration" in record.cause and "[cal] calibration failed: gyro" in record.cause
    assert store == {}


def test_a_store_that_keeps_its_old_values_fails_the_unit_naming_the_parameter(tmp_path):
    """A flash write that did not take: the parameters read back right (they come from the user's file),
    the store read over the shell does not."""
    with px4(tmp_path, SimFaults(factory_store_stale=True)) as sim:
        record = run_unit(station(tmp_path, sim))
    assert record.verdict is Outcome.FAIL
    assert "the factory store holds CAL_MAG0_" in record.cause and "= None (written" in record.cause


def test_a_firmware_without_sys_fac_cal_mode_is_refused_before_anything_is_written(tmp_path):
    with px4(tmp_path, SimFaults(unknown_params=["SYS_FAC_CAL_MODE"])) as sim:
        before = dict(sim.table.values)
        record = run_unit(station(tmp_path, sim))
        after = dict(sim.table.values)
    assert record.verdict is Outcome.FAIL and "this PX4 has no SYS_FAC_CAL_MODE" in record.cause
    assert not record.params_written and after == before


def test_a_backend_without_a_factory_store_is_refused_by_check_saying_why(tmp_path):
    path = write_station("ardupilot-sim.yaml", tmp_path, "tcp:127.0.0.1:5760", {},
                         {"products": {"AP-QUAD-200": {"persist": "factory-storage"}}})
    problems = check_station(path)
    refusal = [p for p in problems if p.key == "products.AP-QUAD-200.persist"]
    assert refusal and refusal[0].line > 0, problems
    assert "the ardupilot backend has no factory-storage" in refusal[0].message
    assert "no factory store for the compass" in refusal[0].message
    (tmp_path / "px4").mkdir()
    accepted = write_station("px4-sim.yaml", tmp_path / "px4", "udpout://127.0.0.1:14550", PX4_OPTIONS,
                             {"products": {PART: {"persist": "factory-storage"}}})
    assert not [p for p in check_station(accepted) if "persist" in p.key]


def test_a_unit_kept_in_parameters_says_so(tmp_path):
    with px4(tmp_path) as sim:
        host, port = sim.address.split(":")[1:]
        record = run_unit(write_station("px4-sim.yaml", tmp_path, f"udpout://{host}:{port}", PX4_OPTIONS))
        store = sim.factory_store()
    assert record.verdict is Outcome.PASS, record.cause
    assert record.persistence["store"] == "parameters (the autopilot parameter storage)" and store == {}


def test_bsondump_s_print_is_read_to_its_own_rounding_and_only_the_store_s_parameters_are_asked():
    """``bsondump`` prints a float32 with six decimals: within that rounding it is the value written; the
    store holds CAL_* but not *_PRIO nor CAL_MAG_SIDES (``filter_calibration_params``)."""
    from magline.plugins.px4.factory_store import held_by_store, store_contents

    printed = ("BSON_DOUBLE: CAL_MAG0_XOFF = 0.974425\nBSON_INT32:  CAL_MAG0_ID = 396809\n"
               "BSON_DOUBLE: CAL_MAG0_YOFF = 0.100000\nBSON_EOO\n")
    written = {"CAL_MAG0_XOFF": 0.9744255156439179, "CAL_MAG0_ID": 396809, "CAL_MAG0_YOFF": 0.1000042,
               "CAL_MAG0_ZOFF": 0.2, "CAL_MAG0_PRIO": 75}
    held = store_contents(printed, written)
    assert held == {"CAL_MAG0_XOFF": 0.9744255156439179, "CAL_MAG0_ID": 396809, "CAL_MAG0_YOFF": 0.1,
                    "CAL_MAG0_ZOFF": None}
    assert not held_by_store("CAL_MAG_SIDES") and held_by_store("TC_A0_ID") and held_by_store("CAL_GYRO0_XOFF")
