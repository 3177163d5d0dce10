"""The FlightAxis-protocol peer that drives ArduPilot's SITL with a known tumble and battery current
(``magline.sitl.ardupilot_flightaxis``): what it answers is what ``SIM_FlightAxis.cpp`` reads, and what SITL
then makes of it is the unit's attitude, rates, specific force and current."""

from __future__ import annotations

import re
import socket
import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from magline.sim.load import LoadSim
from magline.sitl.ardupilot_flightaxis import (
    FRAME_S,
    GRAVITY_MSS,
    KEYS,
    RC_CHANNELS,
    FlightAxisPeer,
    Tumble,
    flightaxis_values,
    reply_body,
)


def sitl_parses(reply: str) -> dict[str, float]:
    """SITL's ``FlightAxis::parse_reply``: each key of its table in turn, found by name from where the last
    one ended (the twelve RC values are all called ``item``), its value read just after the name's ``>``."""
    keys = ["item"] * RC_CHANNELS + list(KEYS)
    values, at = {}, 0
    for n, key in enumerate(keys):
        found = reply.find(key, at)
        if found < 0:
            found = reply.find(key)
        assert found >= 0, f"SITL would stop at 'Failed to find key {key}'"
        start = found + len(key) + 1
        number = re.match(r"-?[0-9.eE+-]+", reply[start:])
        values[f"rc{n}" if key == "item" else key] = float(number[0]) if number else 0.0
        close = reply.find(">", start)
        at = close if close >= 0 else at
    return values


def sitl_sees(values: dict[str, float]) -> tuple[Rotation, np.ndarray]:
    """SITL's ``FlightAxis::update``: its quaternion ``(W, Y, X, −Z)`` (RealFlight's axes) and its gyro
    ``(roll, pitch, −yaw)`` rates."""
    w, x, y, z = (values["m-orientationQuaternion-W"], values["m-orientationQuaternion-Y"],
                  values["m-orientationQuaternion-X"], -values["m-orientationQuaternion-Z"])
    gyro = np.array([values["m-rollRate-DEGpSEC"], values["m-pitchRate-DEGpSEC"], -values["m-yawRate-DEGpSEC"]])
    return Rotation.from_quat([x, y, z, w]), gyro


@pytest.mark.parametrize("euler", [(0, 0, 0), (90, 0, 0), (300, 30, 0), (45, -20, 140)])
def test_sitl_reads_the_unit_s_attitude_and_specific_force_from_the_answer(euler):
    """Held in a pose (heading, pitch, roll), SITL's body → NED attitude is the pose, and the body
    acceleration it takes off the ground is gravity's specific force in the body (−g up)."""
    body_to_ned = Rotation.from_euler("ZYX", euler, degrees=True)
    values = sitl_parses(reply_body(flightaxis_values(body_to_ned, np.zeros(3), 12.5, 20.0, 16.8)))
    attitude, _ = sitl_sees(values)
    assert (attitude * body_to_ned.inv()).magnitude() == pytest.approx(0.0, abs=1e-6)
    accel = [values[f"m-accelerationBody{a}-MPS2"] for a in ("AX", "AY", "AZ")]
    assert accel == pytest.approx(body_to_ned.inv().apply([0, 0, -GRAVITY_MSS]), abs=1e-6)
    assert values["m-isTouchingGround"] == 0.0  # else SITL makes its own acceleration from the velocity
    assert values["m-batteryCurrentDraw-AMPS"] == 20.0 and values["m-batteryVoltage-VOLTS"] == 16.8
    assert values["m-currentPhysicsTime-SEC"] == 12.5 and values["m-flightAxisControllerIsActive"] == 1.0
    assert [values[f"rc{n}"] for n in range(4)] == [0.5, 0.5, 0.0, 0.5]  # throttle low


def test_sitl_reads_the_tumble_s_body_rates():
    peer_rates = np.array([10.0, -25.0, 40.0])
    values = sitl_parses(reply_body(flightaxis_values(Rotation.identity(), peer_rates, 1.0, 0.0, 16.8)))
    _, gyro = sitl_sees(values)
    assert gyro == pytest.approx(peer_rates)


def exchange(port: int, action: str = "ExchangeData") -> str:
    """One request as SITL sends it (a new connection each time), and the reply's body by its length."""
    body = "<?xml version='1.0' encoding='UTF-8'?><soap:Envelope><soap:Body><x/></soap:Body></soap:Envelope>"
    request = (f"POST / HTTP/1.1\nsoapaction: '{action}'\ncontent-length: {len(body)}\n"
               f"content-type: text/xml;charset='UTF-8'\nConnection: Keep-Alive\n\n{body}")
    with socket.create_connection(("127.0.0.1", port), timeout=5) as conn:
        conn.sendall(request.encode())
        data = b""
        while b"\r\n\r\n" not in data:
            data += conn.recv(4096)
        head, _, rest = data.partition(b"\r\n\r\n")
        length = int(re.search(rb"Content-Length: (\d+)", head)[1])
        while len(rest) < length:
            rest += conn.recv(4096)
    return rest.decode()


@pytest.fixture
def load_and_peer():
    load = LoadSim("tcp:127.0.0.1:0").start()
    peer = FlightAxisPeer(Tumble(still_s=0.0, speed=1.0), load.sinking_current, lambda: load.input_on, port=0)
    peer.start()
    yield load, peer, peer.listener.getsockname()[1]
    peer.stop()
    load.stop()


def test_the_peer_answers_sitl_s_requests_over_tcp_with_the_load_s_current(load_and_peer):
    """SITL's connection sequence (restore, inject, then data exchanges) is answered, each by its length; the
    battery current is what the electronic load sinks, and SITL's clock advances with the peer's."""
    load, _, port = load_and_peer
    assert "RestoreOriginalControllerDevice" in exchange(port, "RestoreOriginalControllerDevice")
    assert "InjectUAVControllerInterface" in exchange(port, "InjectUAVControllerInterface")
    first = sitl_parses(exchange(port))
    assert first["m-batteryCurrentDraw-AMPS"] == 0.0
    load.command("CURR", "25.5")
    load.command("INP", "ON")
    later = sitl_parses(exchange(port))
    assert later["m-batteryCurrentDraw-AMPS"] == 25.5
    assert later["m-currentPhysicsTime-SEC"] > first["m-currentPhysicsTime-SEC"]


def test_the_unit_is_held_still_while_the_load_s_input_is_on_and_tumbles_on_from_there(load_and_peer):
    """As an operator sets the unit down for the sweep: no rate and one attitude while the input is on."""
    load, peer, port = load_and_peer
    moving = sitl_parses(exchange(port))
    assert np.linalg.norm(sitl_sees(moving)[1]) > 10.0
    load.command("INP", "ON")
    held = [sitl_sees(sitl_parses(exchange(port))) for _ in range(2)]
    time.sleep(0.05)
    held.append(sitl_sees(sitl_parses(exchange(port))))
    assert all(np.linalg.norm(gyro) == 0.0 for _, gyro in held)
    assert all((a * held[0][0].inv()).magnitude() < 1e-9 for a, _ in held)
    stood = peer.motion_s
    load.command("INP", "OFF")
    time.sleep(0.05)
    resumed_attitude, resumed_gyro = sitl_sees(sitl_parses(exchange(port)))
    assert np.linalg.norm(resumed_gyro) > 10.0
    assert peer.motion_s == stood and (resumed_attitude * held[0][0].inv()).magnitude() < 1e-9  # on from there
    for _ in range(20):
        later_attitude, _ = sitl_sees(sitl_parses(exchange(port)))
    assert peer.motion_s - stood == pytest.approx(20 * FRAME_S)  # the tumble's clock runs again, a frame an answer
    assert (later_attitude * held[0][0].inv()).magnitude() > 0.0


def test_sitl_s_clock_advances_a_frame_per_answer_and_never_ahead_of_the_wall_clock(load_and_peer):
    """SITL extrapolates while an answer is late and never takes its clock back: against a wall clock it ran
    ahead and then skipped what it had run past (the unit jumped 7–20°).  Each answer is one frame of physics
    later than the one before, and is given no sooner than the wall clock reaches it."""
    _, peer, port = load_and_peer
    times = [sitl_parses(exchange(port))["m-currentPhysicsTime-SEC"] for _ in range(40)]
    assert np.diff(times) == pytest.approx(np.full(39, FRAME_S), abs=1e-9)
    assert time.monotonic() - peer.started >= times[-1]
