"""The INAV backend (issue 47) against the INAV simulator over MSP on a real loopback socket: a whole unit
calibrated through INAV's own settings and proven after its reboot; what INAV does that a station must
handle (a calibrated-and-aligned stream, settings in their own widths, arming, another firmware, a save
that did not persist, another board after the reboot, a mounting only ``align_mag`` can fix)."""

from __future__ import annotations

import struct
import time
from pathlib import Path

import numpy as np
import pytest
from simstation import FAST_SENSOR_HZ, run_unit, write_station

from magline.core.links.msp import Msp, MspClient, SettingInfo, encode_setting_info, parse_setting_info
from magline.core.plugins import load_plugins
from magline.core.record import Outcome
from magline.core.station import load_station
from magline.plugin import INAV_TO_FRD, inav_rotation_in_frd
from magline.plugins.inav.calibration import alignment_for, fit_to_settings, mav_orientation
from magline.sim import SimFaults, create_sim
from magline.sim.inav import COUNTS_PER_GAUSS, SETTINGS
from magline.sim.magnetometers import SimMagnetometer
from magline.testing import check_dut_backend
from magline.testing.sims import POLLED_SPEED

OPTIONS = {"connect_timeout_s": 4.0, "boot_timeout_s": 8.0}
COUNTS_PER_UT = COUNTS_PER_GAUSS / 100.0


def board(tmp_path: Path, faults: SimFaults | None = None, **options):
    return create_sim("inav", "tcp:127.0.0.1:0", workdir=tmp_path / "fc", seed=11, boot_time_s=0.3, speed=POLLED_SPEED,
                      mag_rate_hz=FAST_SENSOR_HZ, faults=faults, **options)


def station(tmp_path: Path, address: str, **changes) -> Path:
    return write_station("inav-sim.yaml", tmp_path, address, {**OPTIONS, **changes.pop("options", {})}, changes)


def measured(record, name: str) -> float:
    return next(m.value for m in record.measurements if m.name == name)


PREVIOUS = {"magzero_x": 120, "magzero_y": -80, "magzero_z": 15, "maggain_x": 1500, "maggain_y": 1480,
            "maggain_z": 1530}


def calibrated_before(sim, previous: dict = PREVIOUS) -> None:
    """The unit holds a calibration of its own (a re-test, or INAV's own calibration from a bench)."""
    sim.write_storage({**sim.table.values, **previous})
    sim.load_from_storage(sim.read_storage())


def stored(sim) -> dict:
    return sim.read_storage()


def test_a_setting_s_description_reads_as_inav_lays_it_out():
    """``mspSettingInfoCommand``: the name and a NUL, group, type, section, mode, min (i32), max (u32), index,
    two profile bytes, the value names of a lookup setting, then the value in the setting's own width."""
    align = SettingInfo("align_mag", 7, 0, 0, 0x40, 0, 8, 12, ("DEFAULT", "CW0", "CW90", "CW180", "CW270", "CW0FLIP",
                                                             "CW90FLIP", "CW180FLIP", "CW270FLIP"), 8)
    gain = SettingInfo("maggain_x", 7, 3, 0, 0, -32768, 32767, 5, (), 1024)
    for info in (align, gain):
        assert parse_setting_info(info.name, encode_setting_info(info)) == info
    assert encode_setting_info(gain)[:12] == b"maggain_x\0" + struct.pack("<H", 7)
    assert len(encode_setting_info(gain)) == 10 + 19
    with pytest.raises(ValueError, match="asked for maggain_y names maggain_x"):
        parse_setting_info("maggain_y", encode_setting_info(gain))
    assert gain.encode(-25536) == struct.pack("<h", -25536) and len(gain.encode(1024)) == 2
    with pytest.raises(ValueError, match="maggain_x"):
        parse_setting_info("maggain_x", encode_setting_info(gain)[:10])


def test_the_simulator_is_true_to_inav_over_msp(tmp_path):
    """Identity, a value sent wider than its setting stored truncated (seen on SITL), a write used at once
    and lost at a reboot unless saved, DEFAULT alignment reading back as CW270FLIP, the uptime of the new
    boot, and the compass calibrated and aligned in MSP_RAW_IMU."""
    with board(tmp_path) as sim:
        client = MspClient.connect(sim.address)
        assert client.request(Msp.FC_VARIANT) == b"INAV" and list(client.request(Msp.FC_VERSION)) == [9, 1, 0]
        info = parse_setting_info("align_mag", client.request(Msp.COMMON_SETTING_INFO, b"align_mag\0"))
        assert info.value == 8 and info.names[8] == "CW270FLIP"
        client.request(Msp.COMMON_SET_SETTING, b"maggain_x\0" + struct.pack("<i", 40000))
        assert struct.unpack("<h", client.request(Msp.COMMON_SETTING, b"maggain_x\0"))[0] == -25536
        client.request(Msp.COMMON_SET_SETTING, b"magzero_y\0" + struct.pack("<h", 321))
        sensor = sim.detected[0]
        raw = sim.raw_counts(sensor.read_ut(np.array([20.0, -10.0, 40.0]), np.random.default_rng(1)))
        expected_x = int((raw[0] - 0) * 1024 / -25536)  # C division: toward zero
        out = sim.magnetometer_out(raw)
        assert out[1] == -expected_x  # CW270FLIP: body y = −sensor x
        assert out[0] == -int((raw[1] - 321) * 1024 / 1024)
        client.request(Msp.REBOOT)
        client.close()
        client = reconnect(sim)
        assert struct.unpack("<h", client.request(Msp.COMMON_SETTING, b"magzero_y\0"))[0] == 0  # never saved
        assert struct.unpack_from("<I", client.request(Msp.INAV_MISC2))[0] <= 1
        client.request(Msp.COMMON_SET_SETTING, b"magzero_y\0" + struct.pack("<h", 321))
        client.request(Msp.EEPROM_WRITE)
        assert stored(sim)["magzero_y"] == 321 and sim.boots == 2
        imu = struct.unpack("<9h", client.request(Msp.RAW_IMU))
        assert 450 < np.linalg.norm(imu[0:3]) < 575  # 1 g = 512
        client.close()


def test_the_simulator_speaks_in_inav_s_body_axes_forward_left_up(tmp_path):
    """INAV's body is forward-left-up (``flight/imu.c``; its accelerometer reads +1 g on Z at rest, the compass
    in the same axes): level and facing north under a field that dips down, the accelerometer's Z and the
    compass's Z have opposite signs; nose east, north lies to the left (+Y); nose up 30°, the specific force
    along X is +g/2.  A board in forward-right-down axes reads the field's Z the sign of the accelerometer's."""
    from scipy.spatial.transform import Rotation

    clean = SimMagnetometer(device_id=1, hard_iron_ut=np.zeros(3), soft_iron=np.eye(3), noise_ut=0.0)
    with board(tmp_path, magnetometers=[clean]) as sim:
        client = MspClient.connect(sim.address)

        def raw_imu(attitude: Rotation) -> tuple[np.ndarray, np.ndarray]:
            sim._still = (attitude, time.monotonic())  # the unit held still in that attitude (body → NED)
            sim._held.clear()  # the compass's next reading is of this attitude
            values = np.array(struct.unpack("<9h", client.request(Msp.RAW_IMU)), float)
            return values[0:3] / 512.0, values[6:9] / COUNTS_PER_UT

        north, _, down = sim.field_ned
        assert north > 0 and down > 0  # the simulated site's field dips down
        accel_g, field = raw_imu(Rotation.identity())
        assert accel_g == pytest.approx([0, 0, 1], abs=0.01)
        assert field == pytest.approx([north, 0, -down], abs=0.5)
        _, field = raw_imu(Rotation.from_euler("z", 90, degrees=True))  # nose east
        assert field == pytest.approx([0, north, -down], abs=0.5)
        accel_g, _ = raw_imu(Rotation.from_euler("y", 30, degrees=True))  # nose up
        assert accel_g == pytest.approx([0.5, 0, np.cos(np.radians(30))], abs=0.01)
        client.close()


def reconnect(sim, timeout_s: float = 5.0) -> MspClient:
    import time

    deadline = time.monotonic() + timeout_s
    while True:
        time.sleep(0.1)
        try:
            client = MspClient.connect(sim.address, connect_timeout_s=0.5)
            client.request(Msp.API_VERSION)
            return client
        except Exception:
            if time.monotonic() > deadline:
                raise


def test_the_simulator_refuses_a_save_while_armed_and_ignores_a_reboot(tmp_path):
    with board(tmp_path, SimFaults(armed=True)) as sim:
        client = MspClient.connect(sim.address)
        client.request(Msp.COMMON_SET_SETTING, b"magzero_x\0" + struct.pack("<h", 5))  # accepted while armed
        from magline.core.links.msp import MspRefused

        with pytest.raises(MspRefused):
            client.request(Msp.EEPROM_WRITE)
        assert client.request(Msp.REBOOT) == b""
        import time

        time.sleep(0.6)
        assert sim.boots == 1 and client.request(Msp.FC_VARIANT) == b"INAV"
        client.close()


def test_a_whole_inav_unit_is_calibrated_saved_rebooted_and_proven(tmp_path):
    """The offsets and gains written are the sensor's truth in INAV's terms (the fit's own σ decides how
    close), INAV's calibrated output after the reboot reads the reference, and INAV itself no longer says
    the compass is uncalibrated."""
    with board(tmp_path) as sim:
        record = run_unit(station(tmp_path, sim.address))
        truth = sim.magnetometers[0]
        values = stored(sim)
    assert record.verdict is Outcome.PASS, record.cause
    assert record.unit_info["autopilot"] == "INAV" and record.unit_info["soft_iron_model"] == "diagonal"
    uid = sim.uid & 0xFFFFFFFF, sim.uid >> 32, sim.system_id  # the unit's identity: the MCU's three words
    assert record.unit_info["uid"] == struct.pack("<III", *uid).hex() and record.unit_info["firmware"] == "9.1.0"
    assert record.params_read_back == record.params_written
    assert record.persistence["method"] == "link-reboot"  # MSP_REBOOT, not a MAVLink command it never sent
    sigma = np.asarray(record.calibration["hard_iron_sigma_ut"], float)
    zero = np.array([values[f"magzero_{a}"] for a in "xyz"])
    true_zero = np.array(INAV_TO_FRD, float) @ truth.hard_iron_ut * COUNTS_PER_UT  # in INAV's sensor axes
    assert np.all(np.abs(zero - true_zero) <= 4 * sigma * COUNTS_PER_UT + 1)
    gains = np.array([values[f"maggain_{a}"] for a in "xyz"])
    true_gains = COUNTS_PER_UT * record.calibration["field_ut"] / np.diag(truth.soft_iron)
    assert np.all(np.abs(gains / true_gains - 1) < 0.01)
    assert measured(record, "field_error_pct") == pytest.approx(0.0, abs=5.0)
    # the compass and the accelerometer in one body frame: the field dips as the reference says (it read
    # −126° off when the accelerometer was taken upside down) and the mounting is the one INAV holds
    assert abs(measured(record, "inclination_error_deg")) < 2.0
    assert measured(record, "mounting_error_deg") < 3.0


def test_an_armed_unit_is_an_error_that_says_to_disarm_and_nothing_is_written(tmp_path):
    with board(tmp_path, SimFaults(armed=True)) as sim:
        before = dict(sim.table.values)
        record = run_unit(station(tmp_path, sim.address))
        after = dict(sim.table.values)
    assert record.verdict is Outcome.ERROR and "disarm" in record.cause
    assert after == before and not record.params_written


def test_betaflight_answering_is_an_error_naming_it(tmp_path):
    with board(tmp_path, SimFaults(msp_variant="BTFL")) as sim:
        record = run_unit(station(tmp_path, sim.address))
    assert record.verdict is Outcome.ERROR and "'BTFL' (Betaflight), not INAV" in record.cause


def test_a_save_that_did_not_persist_fails_the_unit_naming_the_setting(tmp_path):
    with board(tmp_path, SimFaults(no_persist=["magzero_x"])) as sim:
        record = run_unit(station(tmp_path, sim.address))
    assert record.verdict is Outcome.FAIL and "magzero_x" in record.cause, record.cause


def test_another_board_after_the_reboot_is_an_error(tmp_path):
    with board(tmp_path, SimFaults(uid_changes_at_reboot=True)) as sim:
        record = run_unit(station(tmp_path, sim.address))
    assert record.verdict is Outcome.ERROR and "MCU UID" in record.cause and "another board" in record.cause


def test_a_unit_that_fails_validation_gets_its_previous_calibration_back_in_ram_and_storage(tmp_path):
    """The neutral calibration written for the tumble is undone: INAV holds what it held before."""
    with board(tmp_path) as sim:
        previous = PREVIOUS
        calibrated_before(sim)
        record = run_unit(station(tmp_path, sim.address,
                                  products={"INAV-WING-300": {"limits": {"hard_iron_norm_ut": {"le": 1.0}}}}))
        ram = {k: sim.table.values[k] for k in previous}
        kept = {k: stored(sim)[k] for k in previous}
    assert record.verdict is Outcome.FAIL and not record.params_written
    assert ram == previous and kept == previous


def test_a_compass_mounted_otherwise_is_named_in_inav_s_terms_and_fixed_with_align_mag(tmp_path):
    """INAV's CW90FLIP turns (x, y, z) into (y, x, −z) in its forward-left-up axes: in magline's
    forward-right-down ones that is Roll180Yaw270 (14), the mounting the simulated compass is given."""
    cw90flip = mav_orientation(inav_rotation_in_frd([[0, 1, 0], [1, 0, 0], [0, 0, -1]]))
    assert cw90flip == 14 and alignment_for(cw90flip) == 6
    assert alignment_for(2) == 2  # a compass turned 90° clockwise seen from above: Yaw90, INAV's CW90
    with board(tmp_path, SimFaults(mag_mounting=[f"1:{cw90flip}"])) as sim:
        record = run_unit(station(tmp_path, sim.address))
    assert record.verdict is Outcome.FAIL and "set align_mag = 6" in record.cause
    with board(tmp_path / "fix", SimFaults(mag_mounting=[f"1:{cw90flip}"])) as sim:
        record = run_unit(station(tmp_path / "fix", sim.address, products={"INAV-WING-300": {"orientation": "fix"}}))
        held = stored(sim)["align_mag"]
    assert record.verdict is Outcome.PASS, record.cause
    assert record.params_written["align_mag"] == 6 and held == 6


def test_a_value_inav_cannot_hold_is_refused_before_anything_is_written(tmp_path):
    with board(tmp_path) as sim:
        dut = backend(station(tmp_path, sim.address))
        dut.connect()
        before = dict(sim.table.values)
        with pytest.raises(Exception, match=r"maggain_x = 40000 is outside INAV's range \[-32768, 32767\]"):
            dut.write_params({"magzero_x": 10, "maggain_x": 40000})
        assert dict(sim.table.values) == before
        dut.close()


def test_a_soft_iron_inav_cannot_hold_is_named_by_the_misfit(tmp_path):
    """Cross terms of 0.08: the diagonal model INAV holds misfits the unit, and the station's limit on the
    heading it would cost FAILs it by name, nothing written."""
    soft = np.array([[1.0, 0.08, 0.0], [0.08, 1.02, 0.05], [0.0, 0.05, 0.97]])
    compass = SimMagnetometer(device_id=1, hard_iron_ut=np.array([20.0, -15.0, 8.0]), soft_iron=soft)
    with board(tmp_path, magnetometers=[compass]) as sim:
        record = run_unit(station(tmp_path, sim.address))
    assert measured(record, "model_misfit_deg") > 2.0
    assert record.verdict is Outcome.FAIL and "model_misfit_deg" in record.cause and not record.params_written


def test_the_inav_backend_meets_the_contract_on_its_simulator(magline_inav, tmp_path):
    """As a plugin author tests a backend: the testing kit's simulated INAV and its conformance suite."""
    fc = magline_inav(seed=11)
    path = station(tmp_path, fc.connection)
    figures = check_dut_backend(lambda: backend(path), fc.sim.field_ut, rate_hz=200.0,
                                hard_iron_ut=fc.sim.magnetometers[0].hard_iron_ut, unsaved_writes="lost")
    assert figures["fit"].residual_rms_ut < 1.0


def test_inav_s_settings_are_written_in_their_own_widths_from_a_fit():
    from magline.core.fit import FitOptions, fit_calibration

    rng = np.random.default_rng(3)
    v = rng.normal(size=(600, 3))
    v = v / np.linalg.norm(v, axis=1, keepdims=True) * 48.0
    soft = np.diag([1.02, 0.97, 1.01])
    raw = (np.linalg.inv(soft) @ v.T).T + np.array([30.0, -12.0, 5.0])
    fit = fit_calibration(raw, FitOptions(field_ut=48.0, model="diagonal", coverage_bins=40))
    settings = fit_to_settings(fit, COUNTS_PER_UT)
    # the fit's axes are forward-right-down, INAV's sensor axes forward-left-up: y and z change sign
    assert settings["magzero_x"] == 900 and settings["magzero_y"] == 360 and settings["magzero_z"] == -150
    assert settings["maggain_x"] == round(COUNTS_PER_UT * 48.0 / 1.02)
    assert all(isinstance(v, int) for v in settings.values())
    assert {s.name for s in SETTINGS} >= set(settings)


def backend(path: Path):
    st, plugins = load_station(path), load_plugins()
    product = st.products[st.default_part]
    options = plugins.options("dut backend", product.backend, product.options, "products.x.options")
    return plugins.dut_backends[product.backend](product, options)


def test_a_whole_inav_unit_runs_over_a_serial_port_across_its_reboot(tmp_path):
    """INAV on USB: the MSP client on a serial port (a pseudo-terminal behind a udev-style name that goes and
    comes back at the reboot, as a board re-enumerating does)."""
    port = tmp_path / "dev" / "serial" / "by-id" / "usb-INAV_SITL-if00"
    with create_sim("inav", f"serial:{port}", workdir=tmp_path / "fc", seed=11, boot_time_s=0.3, speed=POLLED_SPEED,
                    mag_rate_hz=FAST_SENSOR_HZ) as sim:
        record = run_unit(station(tmp_path, f"serial:{port}"))
        nodes = list(sim.link.devices)
    assert record.verdict is Outcome.PASS, record.cause
    assert len(nodes) == 2 and nodes[0] != nodes[1]


def test_the_link_lost_mid_tumble_is_an_error_with_the_raw_data_kept_and_the_unit_told_to_be_retested(tmp_path):
    with board(tmp_path, SimFaults(link_loss_after_s=1.0)) as sim:
        calibrated_before(sim)
        record = run_unit(station(tmp_path, sim.address))
    assert record.verdict is Outcome.ERROR and "MSP" in record.cause
    assert record.attempts and record.attempts[0].samples > 0
    # the neutral calibration written for the tumble could not be undone: each setting named with its value
    neutral = {n: 1024 if n.startswith("maggain") else 0 for n in PREVIOUS}
    assert record.left_changed == {n: f"{neutral[n]} (was {v})" for n, v in PREVIOUS.items()}


def test_a_board_that_answers_later_than_the_reply_timeout_now_and_then_passes(tmp_path):
    """The board's output held 1.5 s of every 5 s (a host that reads its port late, a USB bus that stalls, a
    board writing its flash), longer than the 1 s reply timeout: each request caught in a hold is sent again, as
    INAV's configurator does, and its late answers are neither lost links nor readings put at the wrong time.
    Before, the first hold ended the unit as an ERROR (no reply to MSP command 102 within 1 s)."""
    with board(tmp_path, SimFaults(link_stalls="1.5:5.0")) as sim:
        record = run_unit(station(tmp_path, sim.address))
    assert record.verdict is Outcome.PASS, record.cause
    assert record.params_read_back == record.params_written
    assert measured(record, "mounting_error_deg") < 3.0  # no reading placed at the time of another


def test_a_reboot_whose_reply_is_lost_is_proven_by_the_new_boot(tmp_path):
    """MSP_REBOOT's reply lost on the way, the board rebooting all the same: the new boot's uptime proves it;
    the request is not sent again (it could reboot the new boot once more)."""
    with board(tmp_path, SimFaults(lose_reboot_ack=True)) as sim:
        record = run_unit(station(tmp_path, sim.address))
        reboots = sim.boots
    assert record.verdict is Outcome.PASS, record.cause
    assert record.persistence["method"] == "link-reboot" and reboots == 2


def test_a_reboot_that_never_comes_back_is_an_error_and_nothing_is_claimed(tmp_path):
    with board(tmp_path, SimFaults(reboot_fails=True)) as sim:
        record = run_unit(station(tmp_path, sim.address, options={"boot_timeout_s": 2.0}))
    assert record.verdict is Outcome.ERROR and "did not come back" in record.cause
    assert not record.params_read_back


def test_a_firmware_without_a_calibration_setting_fails_the_unit_naming_it(tmp_path):
    """An INAV build without ``maggain_z`` (a target built without it, an old release) cannot hold the
    calibration: the firmware answers the setting's description with an error reply, and the unit FAILs."""
    with board(tmp_path) as sim:
        del sim.settings["maggain_z"]
        record = run_unit(station(tmp_path, sim.address))
    assert record.verdict is Outcome.FAIL and "this INAV has no setting maggain_z" in record.cause
    assert not record.params_written


def test_an_external_compass_turned_by_its_angles_is_checked_and_fixed_in_those_angles(tmp_path):
    """``align_mag_roll/pitch/yaw`` (0.1°) replace ``align_mag`` for an external compass (INAV's
    ``rotationMatrixFromAngles``, applied transposed): a compass on a mast turned 45° in yaw and set so
    passes, its readings turned back by those angles; one turned 100° while the angles still say 45° fails
    naming the angles of the right-angle mounting nearest it (90°), in INAV's 0.1° units.  (135°, half-way
    between two right angles, once named 180° instead: a test must not sit on the fence it judges.)"""
    from scipy.spatial.transform import Rotation

    from magline.plugin import inav_external_rotation

    def mast(folder: Path, turned_dd: int):
        """A board whose stored angles say 45° and whose compass is turned ``turned_dd`` (the compass takes
        its alignment at boot: stored before the board starts)."""
        sim = board(folder)
        sim.workdir.mkdir(parents=True, exist_ok=True)
        sim.write_storage({"align_mag_yaw": 450})
        turned = inav_rotation_in_frd(inav_external_rotation(0, 0, turned_dd))  # the engine's axes are FRD
        sim.magnetometers[0].rotation = Rotation.from_matrix(turned)
        return sim

    with mast(tmp_path, 450) as sim:
        record = run_unit(station(tmp_path, sim.address))
    assert record.verdict is Outcome.PASS, record.cause
    assert measured(record, "mounting_error_deg") < 3.0
    with mast(tmp_path / "wrong", 1000) as sim:
        record = run_unit(station(tmp_path / "wrong", sim.address))
    assert record.verdict is Outcome.FAIL
    assert "set align_mag_roll = 0, align_mag_pitch = 0, align_mag_yaw = 900" in record.cause, record.cause


def test_a_compass_that_reads_the_same_at_rest_is_proven_with_what_it_reads(tmp_path):
    """At rest after the power cycle the compass reads the same value at every poll (a quiet sensor whose
    steps are coarser than its noise): the station ended such a unit as an ERROR ("gave 1 distinct
    readings of the 20 asked").  After a bounded wait the repeats are what the compass reads."""
    with board(tmp_path, SimFaults(quiet_at_rest=True)) as sim:
        record = run_unit(station(tmp_path, sim.address))
        assert sim.resting is not None
    assert record.verdict is Outcome.PASS, record.cause
    assert record.persistence["figures"]["calibrated_field_ut"] == pytest.approx(sim.field_ut, rel=0.03)


def test_a_station_that_begins_the_next_unit_at_once_tumbles_it(tmp_path):
    """Two units on one simulated board, the second begun within a second of the first's proof: the station
    writes the neutral calibration before the tumble, and the simulated operator picks the unit up — it
    rested where the power cycle left it, and three attempts of the second unit read 0 % coverage."""
    from magline.core.sequencer import Sequencer

    with board(tmp_path) as sim:
        seq = Sequencer(load_station(station(tmp_path, sim.address)), load_plugins(), tmp_path,
                        sleep=lambda s: None)
        try:
            records = [seq.run_unit(serial) for serial in ("SN-1", "SN-2")]
        finally:
            seq.close()
    assert [r.verdict for r in records] == [Outcome.PASS, Outcome.PASS], [r.cause for r in records]
