"""The HIL_SENSOR feeder that drives PX4's SITL with a known truth (``magline.sitl.px4_hil``) and the power
control that cuts it (``magline.sitl.px4_power``): what the feeder sends is what PX4's ``simulator_mavlink``
takes, the truth's parameters calibrate its readings as PX4 applies ``CAL_MAGn_*``, and a power cut is a
killed process started again on the same storage."""

from __future__ import annotations

import json
import socket
import sys
import threading
import time
from types import SimpleNamespace

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink
from scipy.spatial.transform import Rotation

from magline.plugins.px4.calibration import fit_to_params
from magline.sim.truth.sensor import earth_field_ned
from magline.sitl.px4_hil import ACCEL, GYRO, MAG, HilFeeder, Px4Truth, attitude, hil_sensor
from magline.sitl.px4_power import Px4Process


def px4_calibrates(truth: Px4Truth, params: dict, raw_gauss: np.ndarray) -> np.ndarray:
    """``CAL_MAG0_*`` applied as PX4's ``calibration::Magnetometer::Correct`` does: ``S·(raw − OFF)``, gauss."""
    p = {k.removeprefix("CAL_MAG0_"): v for k, v in params.items()}
    s = np.array([[p["XSCALE"], p["XODIAG"], p["YODIAG"]], [p["XODIAG"], p["YSCALE"], p["ZODIAG"]],
                  [p["YODIAG"], p["ZODIAG"], p["ZSCALE"]]])
    return s @ (raw_gauss - np.array([p["XOFF"], p["YOFF"], p["ZOFF"]]))


@pytest.mark.parametrize("pose", [(0, 0, 0), (90, 0, 0), (300, 30, 0), (45, -20, 40)])
def test_the_truth_s_parameters_give_px4_the_site_s_field_in_the_body(pose):
    """The parameters the truth says a right calibration writes (as magline's own PX4 mapping writes a fit
    of that truth) turn the compass's readings back into the site's field in the body, in any attitude."""
    truth = Px4Truth.drawn(5, noise_ut=0.0)
    fit = SimpleNamespace(hard_iron_ut=np.asarray(truth.hard_iron_ut), soft_iron=np.asarray(truth.soft_iron))
    params = fit_to_params(fit, 0, 1, 50, with_odiag=True)
    assert {k.removeprefix("CAL_MAG0_"): v for k, v in params.items() if k[9:] in truth.expected} == pytest.approx(
        truth.expected)
    body_to_ned = Rotation.from_euler("ZYX", pose, degrees=True)
    raw = truth.raw_gauss(body_to_ned, np.random.default_rng(0))
    field = body_to_ned.inv().apply(earth_field_ned(truth.field_ut, truth.inclination_deg)) / 100.0
    assert px4_calibrates(truth, params, raw) == pytest.approx(field, abs=1e-9)


def test_a_turned_compass_reads_the_field_turned_by_its_mounting():
    truth = Px4Truth.drawn(5, noise_ut=0.0, mounting_yaw_deg=90.0)
    params = {f"CAL_MAG0_{k}": v for k, v in truth.expected.items()}
    body_field = earth_field_ned(truth.field_ut, truth.inclination_deg) / 100.0
    sensor = px4_calibrates(truth, params, truth.raw_gauss(Rotation.identity(), np.random.default_rng(0)))
    assert sensor == pytest.approx(Rotation.from_euler("z", -90, degrees=True).apply(body_field), abs=1e-9)


def test_hil_sensor_holds_the_specific_force_and_the_body_rates_px4_expects():
    """Still and level first: −g on Z (forward-right-down), no turn; then the tumble's own turn between
    its attitudes, in rad/s; the magnetometer only in the messages that carry it."""
    truth = Px4Truth.drawn(5, still_s=1.0)
    rng = np.random.default_rng(0)
    still = hil_sensor(truth, 0.5, 100, True, rng)
    assert (still["xacc"], still["yacc"], still["zacc"]) == pytest.approx((0.0, 0.0, -9.80665))
    assert (still["xgyro"], still["ygyro"], still["zgyro"]) == pytest.approx((0.0, 0.0, 0.0))
    assert still["fields_updated"] & MAG == MAG and still["fields_updated"] & (ACCEL | GYRO) == ACCEL | GYRO
    moving = hil_sensor(truth, 3.0, 200, False, rng, dt_s=0.004)
    step = (attitude(truth, 3.0).inv() * attitude(truth, 3.004)).as_rotvec() / 0.004
    assert np.linalg.norm(step) > 0.5
    assert [moving["xgyro"], moving["ygyro"], moving["zgyro"]] == pytest.approx(step)
    assert moving["fields_updated"] & MAG == 0


def test_the_feeder_serves_px4_over_tcp_and_a_new_connection_starts_the_board_s_clock_afresh():
    """PX4 connects as a TCP client; the feeder sends HIL_SENSOR (its time the board's clock, rising) and
    HIL_GPS; after a power cut the new process connects again and its clock starts over."""
    truth = Px4Truth.drawn(5, still_s=60.0)
    feeder = HilFeeder(truth, port=0)
    port = feeder.server.getsockname()[1]
    threading.Thread(target=feeder.serve, daemon=True).start()

    def boot_and_listen(count: int) -> list:
        parser = mavlink.MAVLink(None)
        got: list = []
        with socket.create_connection(("127.0.0.1", port), timeout=5.0) as px4:
            while len([m for m in got if m.get_type() == "HIL_SENSOR"]) < count:
                got += parser.parse_buffer(px4.recv(4096)) or []
        return got

    try:
        first = boot_and_listen(30)
        again = boot_and_listen(5)
    finally:
        feeder.stop()
    sensors = [m for m in first if m.get_type() == "HIL_SENSOR"]
    times = [m.time_usec for m in sensors]
    assert times == sorted(times) and len(set(times)) == len(times)
    assert any(m.get_type() == "HIL_GPS" and m.fix_type == 3 for m in first)
    mags = [m for m in sensors if m.fields_updated & MAG]
    assert mags and np.linalg.norm([mags[0].xmag, mags[0].ymag, mags[0].zmag]) > 0.1  # gauss, not µT
    restarted = [m.time_usec for m in again if m.get_type() == "HIL_SENSOR"]
    assert restarted[0] < times[-1]
    assert feeder.connections == 2


def test_the_power_control_cuts_the_process_and_starts_it_again_on_the_same_folder(tmp_path):
    """``on`` starts the command ``px4.json`` holds, detached, and keeps its pid; ``off`` kills it at once
    (SIGKILL, as a cut supply) and waits until it is gone; each is a no-op in the state it makes."""
    build = tmp_path / "build"
    (build / "bin").mkdir(parents=True)
    (build / "etc").mkdir()
    px4 = Px4Process.prepare(build, tmp_path / "board")
    spec = json.loads((tmp_path / "board" / "px4.json").read_text())
    assert spec == {"argv": [str(build / "bin" / "px4"), "-d", "-w", str(tmp_path / "board"), str(build / "etc")],
                    "env": {"PX4_SIM_MODEL": "none_iris"}}
    # a stand-in for the firmware: counts its boots in the board's folder, then runs until cut
    spec["argv"] = [sys.executable, "-c", "open('boots', 'a').write('1'); import time; time.sleep(60)"]
    (tmp_path / "board" / "px4.json").write_text(json.dumps(spec))
    boots = tmp_path / "board" / "boots"

    def booted(times: int) -> bool:
        """Whether the stand-in has started ``times`` times (each start is an event it writes, not a wait)."""
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline:
            if boots.is_file() and len(boots.read_text()) >= times:
                return len(boots.read_text()) == times
            time.sleep(0.02)
        return False

    px4.on()
    first = px4.pid()
    assert first is not None and booted(1)
    px4.on()
    assert px4.pid() == first
    px4.off()
    assert px4.pid() is None
    px4.off()
    px4.on()
    assert px4.pid() not in (None, first) and booted(2)
    px4.off()
    assert px4.pid() is None


def test_a_unit_set_down_rests_where_it_was_with_no_turn():
    """``rest()`` (the station said the tumble is done): the motion time stops where it was, the gyro reads
    nothing and the accelerometer and compass read the attitude it was set down in."""
    truth = Px4Truth.drawn(5, still_s=0.0, noise_ut=0.0)
    feeder = HilFeeder(truth, port=0)
    try:
        feeder.started = time.monotonic() - 20.0
        feeder.rest()
        rested, moving = feeder.motion_time(feeder.started)
        assert not moving and rested == pytest.approx(20.0, abs=1.0)
        resting = hil_sensor(truth, rested, 1000, True, np.random.default_rng(0), moving=False)
        tumbling = hil_sensor(truth, rested, 1000, True, np.random.default_rng(0))
        assert (resting["xgyro"], resting["ygyro"], resting["zgyro"]) == (0.0, 0.0, 0.0)
        assert np.linalg.norm([tumbling["xgyro"], tumbling["ygyro"], tumbling["zgyro"]]) > 0.5
        assert [resting[k] for k in ("xacc", "yacc", "zacc", "xmag", "ymag", "zmag")] == pytest.approx(
            [tumbling[k] for k in ("xacc", "yacc", "zacc", "xmag", "ymag", "zmag")])
        assert feeder.motion_time(feeder.started - 5.0) == (rested, False)  # it stays down
    finally:
        feeder.server.close()


@pytest.mark.parametrize("mounting_yaw_deg", [0.0, 90.0])
def test_the_truth_s_compensation_cancels_the_current_s_field_as_px4_applies_it(mounting_yaw_deg):
    """PX4's ``Magnetometer::Correct`` adds ``power·COMP`` (kA, G/kA) to the raw reading before the offset,
    in the sensor's axes: with the truth's calibration and ``xCOMP`` the field is the one without the current
    at any current, whatever the compass's mounting."""
    truth = Px4Truth.drawn(5, noise_ut=0.0, interference_ut_per_a=[0.1, -0.05, 0.08], mounting_yaw_deg=mounting_yaw_deg)
    fit = SimpleNamespace(hard_iron_ut=np.asarray(truth.hard_iron_ut), soft_iron=np.asarray(truth.soft_iron))
    params = fit_to_params(fit, 0, 1, 50, with_odiag=True)
    comp = truth.expected_compensation()
    assert comp["COMP_TYP"] == 2.0
    body_to_ned = Rotation.from_euler("ZYX", (30, 10, -20), degrees=True)
    quiet = px4_calibrates(truth, params, truth.raw_gauss(body_to_ned, np.random.default_rng(0)))
    for amps in (20.0, 40.0):
        raw = truth.raw_gauss(body_to_ned, np.random.default_rng(0), current_a=amps)
        assert np.linalg.norm(px4_calibrates(truth, params, raw) - quiet) > 0.01  # 0.5 µT and more: it moves
        compensated = raw + amps / 1000.0 * np.array([comp[f"{a}COMP"] for a in "XYZ"])
        assert px4_calibrates(truth, params, compensated) == pytest.approx(quiet, abs=1e-9)


def test_the_unit_is_held_still_while_the_load_is_on_and_tumbles_on_from_there():
    """Held for a current sweep (the load's input on), the motion time stands; released, it goes on from where
    it stood — the time held is not a jump in the tumble."""
    truth = Px4Truth.drawn(5, still_s=0.0, noise_ut=0.0)
    held = [False]
    feeder = HilFeeder(truth, port=0, held=lambda: held[0])
    try:
        started = time.monotonic() - 10.0
        before, moving = feeder.motion_time(started)
        assert moving and before == pytest.approx(10.0, abs=0.5)
        held[0] = True
        first, moving = feeder.motion_time(started)
        time.sleep(0.05)
        assert not moving and feeder.motion_time(started) == (first, False)
        held[0] = False
        after, moving = feeder.motion_time(started)
        assert moving and after == pytest.approx(first, abs=1e-6)  # on from where it stood, not 50 ms later
    finally:
        feeder.server.close()


def test_the_power_module_tells_px4_the_current_as_another_component_of_its_system():
    """PX4's ``handle_message_battery_status`` takes a BATTERY_STATUS only from its own system id and another
    component; the current in centi-amps, id 0, a full four-cell pack's voltages and charge."""
    from magline.sitl.px4_hil import BatteryReporter

    reporter = BatteryReporter(lambda: 12.345)
    try:
        (msg,) = mavlink.MAVLink(None).parse_buffer(reporter.frame())
    finally:
        reporter.sock.close()
    assert msg.get_type() == "BATTERY_STATUS" and msg.get_srcSystem() == 1
    assert msg.get_srcComponent() == mavlink.MAV_COMP_ID_BATTERY != mavlink.MAV_COMP_ID_AUTOPILOT1
    assert msg.current_battery == 1234 and msg.id == 0
    assert msg.voltages[:4] == [4200] * 4 and set(msg.voltages[4:]) == {65535}
    assert msg.battery_remaining == 100  # "unknown" (−1) is −1 % to PX4: an emergency it shuts down for


def test_an_integer_parameter_px4_sends_as_its_bytes_is_read_as_the_integer():
    """PX4 encodes an integer parameter's bytes in PARAM_VALUE's float (2 reads 2.8e-45 taken as a float);
    ArduPilot casts it to a float.  The runners read each firmware's way."""
    import struct

    from magline.sitl.checks import param_value

    bits = struct.unpack("<f", struct.pack("<i", 197388))[0]
    px4 = SimpleNamespace(param_value=bits, param_type=mavlink.MAV_PARAM_TYPE_INT32)
    assert param_value(px4, bytewise=True) == 197388.0 and param_value(px4, bytewise=False) < 1e-30
    ardupilot = SimpleNamespace(param_value=2.0, param_type=mavlink.MAV_PARAM_TYPE_INT8)
    assert param_value(ardupilot, bytewise=False) == 2.0
    real = SimpleNamespace(param_value=0.125, param_type=mavlink.MAV_PARAM_TYPE_REAL32)
    assert param_value(real, bytewise=True) == 0.125
