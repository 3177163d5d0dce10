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
