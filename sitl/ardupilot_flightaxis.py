"""A FlightAxis-protocol peer for ArduPilot's SITL (``--model flightaxis``) that turns the vehicle through a
known tumble and draws a known battery current.

Why this peer: ArduCopter's ``calibration`` model tumbles the vehicle but draws no current, and its
multicopter models draw current only from spinning motors and cannot tumble; a compass's current
interference (``SIM_MAG_MOT``, mG per amp of ``battery_current``, added to the body-frame field before
each compass's own distortion) can then be calibrated and swept in one run only when the simulator
supplies both.  SITL's FlightAxis back end (``libraries/SITL/SIM_FlightAxis.cpp``, written for RealFlight)
takes the whole state from its peer: attitude, body rates, specific force, battery voltage and current.

What SITL does with it, and what the peer therefore sends:
- SITL opens a new TCP connection to port 18083 for each request (``RestoreOriginalControllerDevice``,
  ``InjectUAVControllerInterface`` once, then ``ExchangeData`` at 250 Hz) and reads an HTTP reply by its
  ``Content-Length``; it takes each value by searching its key's name, in the order of its key table
  (:data:`KEYS`), so the reply holds every key once, in that order.
- Attitude: SITL builds its quaternion as ``(W, Y, X, −Z)`` of the one sent (RealFlight's axes), so a
  body → NED quaternion ``(w, x, y, z)`` is sent as ``W = w, X = y, Y = x, Z = −z``; body rates
  as roll, pitch and the negated yaw rate (°/s).  Off the ground (``m-isTouchingGround`` 0) the specific
  force is the body acceleration sent (m/s²; at rest ``−g`` turned into the body).
- Time: SITL's clock follows ``m-currentPhysicsTime-SEC``, and the peer's clock advances by one frame
  (:data:`FRAME_S`) per answer, never ahead of the wall clock.  Why not the wall clock itself: while an
  answer is late SITL moves its own clock on by extrapolating (up to a frame at a time) and never takes it
  back unless it is 0.5 s ahead, so against a wall clock SITL's ran about 1 % fast and then skipped the
  motion it had run ahead of — the unit jumped 7–20° in one instant, once or twice a tumble, and the station
  paired its readings across the jump.  With a frame per answer SITL's clock is the motion's.
- Battery: a voltage above zero makes SITL's analog battery monitor read the current sent (else it
  makes its own from the throttle), and SIM_MAG_MOT multiplies the same current.

The current is the simulated electronic load's (:class:`magline.sim.load.LoadSim`): the station's own
current source, as on a line.  While the load's input is on the unit is held still where it is, as an
operator sets it down for the sweep; the tumble goes on from there when the input goes off.
"""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from magline.sim.truth.attitudes import spiral_attitude
from magline.sitl.held_clock import HeldClock

FLIGHTAXIS_PORT = 18083  # SIM_FlightAxis.h controller_port
GRAVITY_MSS = 9.80665
RC_CHANNELS = 12
# SIM_FlightAxis.h's key table after the twelve RC ``item`` values, in its order
KEYS = (
    "m-airspeed-MPS", "m-altitudeASL-MTR", "m-altitudeAGL-MTR", "m-groundspeed-MPS", "m-pitchRate-DEGpSEC",
    "m-rollRate-DEGpSEC", "m-yawRate-DEGpSEC", "m-azimuth-DEG", "m-inclination-DEG", "m-roll-DEG",
    "m-aircraftPositionX-MTR", "m-aircraftPositionY-MTR", "m-velocityWorldU-MPS", "m-velocityWorldV-MPS",
    "m-velocityWorldW-MPS", "m-velocityBodyU-MPS", "m-velocityBodyV-MPS", "m-velocityBodyW-MPS",
    "m-accelerationWorldAX-MPS2", "m-accelerationWorldAY-MPS2", "m-accelerationWorldAZ-MPS2",
    "m-accelerationBodyAX-MPS2", "m-accelerationBodyAY-MPS2", "m-accelerationBodyAZ-MPS2", "m-windX-MPS",
    "m-windY-MPS", "m-windZ-MPS", "m-propRPM", "m-heliMainRotorRPM", "m-batteryVoltage-VOLTS",
    "m-batteryCurrentDraw-AMPS", "m-batteryRemainingCapacity-MAH", "m-fuelRemaining-OZ", "m-isLocked",
    "m-hasLostComponents", "m-anEngineIsRunning", "m-isTouchingGround", "m-currentAircraftStatus",
    "m-currentPhysicsTime-SEC", "m-currentPhysicsSpeedMultiplier", "m-orientationQuaternion-X",
    "m-orientationQuaternion-Y", "m-orientationQuaternion-Z", "m-orientationQuaternion-W",
    "m-flightAxisControllerIsActive", "m-resetButtonHasBeenPressed",
)
RC_CENTRED = (0.5, 0.5, 0.0, 0.5) + (0.0,) * (RC_CHANNELS - 4)  # sticks centred, throttle (channel 3) low
FRAME_S = 0.0025  # the physics advanced per answer: SIM_FlightAxis's 400 Hz frames (it extrapolates between)


@dataclass
class Tumble:
    """The unit's motion: level and still for ``still_s``, then the spiral tumble at ``speed``
    (1: a pole-to-pole sweep in 8 s).  Its clock runs only while the unit is not held.

    Why 0.15 (the unit turning 50°/s, 62°/s at the 90th percentile, about its calibration model's 60°/s):
    ArduCopter's compass drivers hand on the mean of what they sampled since the last read, which falls
    short of the field by the chord each window swept, most across the axis the spiral spins about.  At
    0.25 (83°/s) every compass's written soft iron came out 0.1 % long on X and Y and 0.25 % short on Z,
    6σ of what the station states; at 0.15 every element within 2.1σ."""

    still_s: float = 3.0
    speed: float = 0.15

    def attitude(self, t_s: float) -> Rotation:
        if t_s < self.still_s:
            return Rotation.identity()
        return spiral_attitude(self.speed * (t_s - self.still_s))


def flightaxis_values(body_to_ned: Rotation, rate_frd_dps: np.ndarray, physics_s: float, current_a: float,
                      voltage_v: float) -> dict[str, float]:
    """Every key SITL reads, for the unit in ``body_to_ned`` turning at ``rate_frd_dps`` (body axes)."""
    x, y, z, w = body_to_ned.as_quat()
    specific_force = body_to_ned.inv().apply([0.0, 0.0, -GRAVITY_MSS])
    values = dict.fromkeys(KEYS, 0.0)
    values.update({
        "m-orientationQuaternion-W": w, "m-orientationQuaternion-X": y, "m-orientationQuaternion-Y": x,
        "m-orientationQuaternion-Z": -z,
        "m-rollRate-DEGpSEC": rate_frd_dps[0], "m-pitchRate-DEGpSEC": rate_frd_dps[1],
        "m-yawRate-DEGpSEC": -rate_frd_dps[2],
        "m-accelerationBodyAX-MPS2": specific_force[0], "m-accelerationBodyAY-MPS2": specific_force[1],
        "m-accelerationBodyAZ-MPS2": specific_force[2],
        "m-batteryVoltage-VOLTS": voltage_v, "m-batteryCurrentDraw-AMPS": current_a,
        "m-currentPhysicsTime-SEC": physics_s, "m-currentPhysicsSpeedMultiplier": 1.0,
        "m-anEngineIsRunning": 1.0, "m-flightAxisControllerIsActive": 1.0,
    })
    return values


def reply_body(values: dict[str, float], rc: tuple[float, ...] = RC_CENTRED) -> str:
    """The ``ExchangeData`` answer: the RC values, then every key in SITL's order."""
    items = "".join(f"<item>{v:.4f}</item>" for v in rc)
    fields = "".join(f"<{key}>{values[key]:.9g}</{key}>" for key in KEYS)
    return (f"<?xml version='1.0' encoding='UTF-8'?><soap:Envelope><soap:Body><ReturnData><m-channelValues-0to1>"
            f"{items}</m-channelValues-0to1><m-aircraftState>{fields}</m-aircraftState></ReturnData>"
            "</soap:Body></soap:Envelope>")


def http_reply(body: str) -> bytes:
    data = body.encode()
    return b"HTTP/1.1 200 OK\r\nContent-Type: text/xml;charset='UTF-8'\r\nContent-Length: %d\r\n\r\n%s" % (
        len(data), data)


def read_request(conn: socket.socket) -> str | None:
    """One request's SOAP action (the header SITL sends), once its whole body has arrived."""
    data = b""
    while b"\r\n\r\n" not in data and b"\n\n" not in data:
        chunk = conn.recv(4096)
        if not chunk:
            return None
        data += chunk
    head, _, body = data.replace(b"\r\n", b"\n").partition(b"\n\n")
    headers = {}
    for line in head.split(b"\n")[1:]:
        name, _, value = line.decode("latin-1").partition(":")
        headers[name.strip().lower()] = value.strip()
    length = int(headers.get("content-length", "0"))
    while len(body) < length:
        chunk = conn.recv(4096)
        if not chunk:
            return None
        body += chunk
    return headers.get("soapaction", "").strip("'\"")


class FlightAxisPeer:
    """The peer: answers SITL on ``port`` with the tumble's state, ``current_a()`` amps, held still while
    ``held()`` is true."""

    def __init__(self, tumble: Tumble, current_a: Callable[[], float], held: Callable[[], bool],
                 port: int = FLIGHTAXIS_PORT, voltage_v: float = 16.8) -> None:
        self.tumble, self.current_a, self.held, self.voltage_v = tumble, current_a, held, voltage_v
        self.listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.listener.bind(("127.0.0.1", port))
        self.listener.listen(64)
        self.listener.settimeout(0.2)
        self.started = time.monotonic()
        self.physics_s = 0.0  # the physics clock SITL follows: a frame per answer (module docstring)
        self.lock = threading.Lock()
        self.clock, self.began = HeldClock(), None  # the tumble's clock (from SITL's first exchange)
        self.motion_s = 0.0  # the tumble's time in the last answer
        self.stopped = threading.Event()
        self.thread: threading.Thread | None = None

    def state(self) -> tuple[Rotation, np.ndarray, float]:
        """The unit's attitude and body rates (°/s) one frame on, and the physics clock (s) then; answered no
        sooner than the wall clock reaches it."""
        with self.lock:
            self.physics_s += FRAME_S
            early = self.started + self.physics_s - time.monotonic()
            if early > 0:
                time.sleep(early)
            now = self.started + self.physics_s
            held = self.held()
            self.began = now if self.began is None else self.began
            motion_s = self.motion_s = self.clock.motion_s(self.began, now, held)
            attitude = self.tumble.attitude(motion_s)
            if held:
                rate = np.zeros(3)
            else:
                dt = 0.01
                rate = np.degrees((attitude.inv() * self.tumble.attitude(motion_s + dt)).as_rotvec() / dt)
            return attitude, rate, self.physics_s

    def _answer(self, conn: socket.socket) -> None:
        with conn:
            conn.settimeout(2.0)
            try:
                action = read_request(conn)
                if action is None:
                    return
                if action == "ExchangeData":
                    attitude, rate, physics_s = self.state()
                    body = reply_body(flightaxis_values(attitude, rate, physics_s, float(self.current_a()),
                                                        self.voltage_v))
                else:  # RestoreOriginalControllerDevice, InjectUAVControllerInterface, ResetAircraft
                    body = f"<?xml version='1.0' encoding='UTF-8'?><{action}Response/>"
                conn.sendall(http_reply(body))
            except OSError:
                return

    def serve(self) -> None:
        while not self.stopped.is_set():
            try:
                conn, _ = self.listener.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            threading.Thread(target=self._answer, args=(conn,), daemon=True).start()

    def start(self) -> FlightAxisPeer:
        self.thread = threading.Thread(target=self.serve, name="FlightAxisPeer", daemon=True)
        self.thread.start()
        return self

    def stop(self) -> None:
        self.stopped.set()
        if self.thread is not None:
            self.thread.join(timeout=2.0)
        self.listener.close()
