"""The X-Plane-protocol peer that drives INAV's SITL with a known truth (``magline.sitl.inav_xplane``): what it
sends is what INAV's ``xplane.c`` expects, and what INAV then makes of it is the truth in INAV's own axes."""

from __future__ import annotations

import socket
import struct
import threading

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from magline.plugin import INAV_ALIGNMENTS, INAV_TO_FRD
from magline.sim.truth.sensor import earth_field_ned
from magline.sitl.inav_xplane import InavTruth, XPlanePeer, attitude, parse_rref_request, rref_packet, xplane_values


def inav_sees(values: dict[str, float], truth: InavTruth) -> tuple[np.ndarray, np.ndarray]:
    """What INAV's SITL makes of the values (``xplane.c``): its fake accelerometer ``(−axil, side, nrml)`` g,
    and the compass's counts through a calibration that is the truth and the alignment the compass sits at."""
    accel = np.array([-values["sim/flightmodel/forces/g_axil"], values["sim/flightmodel/forces/g_side"],
                      values["sim/flightmodel/forces/g_nrml"]])
    raw_ut = np.array([values[f"inav_xitl/sensors/magnetometer[{i}]"] for i in range(3)]) * 100.0
    calibrated = (raw_ut - truth.hard_iron_ut) * np.asarray(truth.soft_iron_diag)
    return accel, np.array(INAV_ALIGNMENTS[truth.alignment], float) @ calibrated


@pytest.mark.parametrize("pose", [(0, 0, 0), (90, 0, 0), (300, 30, 0), (45, -20, 40)])
def test_inav_is_fed_the_unit_s_attitude_in_its_own_axes(pose):
    """Held still in a pose (heading, pitch, roll): INAV's accelerometer reads the specific force and its
    compass the site's field, both in its forward-left-up body axes."""
    truth = InavTruth.drawn(3, poses=[list(pose)], still_s=0.0, noise_ut=0.0)
    body_to_ned = Rotation.from_euler("ZYX", pose, degrees=True)
    values = xplane_values(truth, 1.0, np.random.default_rng(0))
    accel, field = inav_sees(values, truth)
    flip = np.array(INAV_TO_FRD, float)
    assert accel == pytest.approx(flip @ body_to_ned.inv().apply([0, 0, -1.0]), abs=1e-6)
    assert field == pytest.approx(flip @ body_to_ned.inv().apply(earth_field_ned(48.0, 62.0)), abs=1e-6)
    assert values["sim/flightmodel/position/psi"] == pytest.approx(pose[0] % 360)
    assert values["sim/flightmodel/position/theta"] == pytest.approx(pose[1])
    assert values["sim/flightmodel/position/phi"] == pytest.approx(pose[2])


def test_the_tumble_s_body_rates_are_the_turn_between_its_attitudes():
    truth = InavTruth.drawn(3, still_s=0.0)
    values = xplane_values(truth, 2.0, np.random.default_rng(0))
    rate = np.radians([values[f"sim/flightmodel/position/{a}"] for a in "PQR"])
    step = (attitude(truth, 2.0).inv() * attitude(truth, 2.01)).as_rotvec() / 0.01
    assert np.linalg.norm(rate) > 0.5 and rate == pytest.approx(step, rel=0.02, abs=0.01)


def test_the_truth_says_what_a_right_calibration_writes():
    truth = InavTruth(hard_iron_ut=[10.0, -20.0, 5.5], soft_iron_diag=[1.05, 0.96, 1.0], field_ut=48.0)
    assert truth.expected == {"magzero_x": 102, "magzero_y": -205, "magzero_z": 56, "maggain_x": 468,
                              "maggain_y": 512, "maggain_z": 492, "align_mag": 8}


def test_the_peer_answers_what_inav_asks_over_udp():
    """INAV registers each reference (frequency, its index, the name) and reads (index, value) pairs; one
    registered at frequency 0 is no longer sent."""
    truth = InavTruth.drawn(3, still_s=10.0)
    peer = XPlanePeer(truth, port=0, rate_hz=100.0)
    port = peer.sock.getsockname()[1]
    threading.Thread(target=peer.serve, daemon=True).start()
    inav = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    inav.settimeout(2.0)
    try:
        def register(frequency: int, index: int, name: str) -> None:
            packet = b"RREF\0" + struct.pack("<II", frequency, index) + name.encode() + b"\0"
            assert parse_rref_request(packet) == (frequency, index, name)
            inav.sendto(packet.ljust(413, b"\0"), ("127.0.0.1", port))

        register(100, 0, "inav_xitl/plugin/xitlDrefVersion")
        register(100, 17, "sim/flightmodel/forces/g_nrml")
        register(100, 30, "sim/flightmodel/position/P")
        register(0, 30, "sim/flightmodel/position/P")
        got: dict[int, float] = {}
        while set(got) != {0, 17}:
            packet = inav.recv(1024)
            assert packet[:5] == b"RREF\0"
            got = dict(struct.unpack_from("<If", packet, 5 + 8 * i) for i in range((len(packet) - 5) // 8))
        assert got[0] == 2.0 and got[17] == pytest.approx(1.0)  # XITL version 2; still and level: 1 g
    finally:
        inav.close()
        peer.stop()
    assert rref_packet([(1, 2.5)]) == b"RREF\0" + struct.pack("<If", 1, 2.5)
