"""A HIL_SENSOR feeder for PX4's SITL (``PX4_SIM_MODEL=none_iris``) that tumbles a compass of known truth.

PX4's ``simulator_mavlink`` connects as a TCP client to port 4560 and takes its sensors from whoever serves
there: ``HIL_SENSOR`` (accelerometer m/s², gyro rad/s, both forward-right-down; magnetometer in gauss;
pressure) and ``HIL_GPS``.  Its clock follows ``HIL_SENSOR.time_usec`` (lockstep), so the feeder sends at a
steady rate and its own elapsed time is the board's.  After a power cut the new PX4 process connects
again: the feeder accepts it and starts the board's clock afresh, while the unit keeps tumbling.

What the feeder sends is the unit's true motion (still and level first: PX4's estimator and gyro
calibration want a quiet start) and the compass's reading of the site's field in the unit's body,
turned by the compass's true mounting and distorted by the truth (``m = S⁻¹·R_mount⁻¹·b + h``).  The
truth (a JSON file beside the run) holds the distortion, the mounting, the field, and the parameters a
right calibration writes: ``CAL_MAGn_xOFF = h`` in gauss and the scale matrix ``S`` (PX4 applies
``S·(raw − OFF)`` in the sensor's axes).

For a current sweep the feeder also knows a battery current (a simulated electronic load's): the board's
wiring adds ``I·c`` (µT, body axes) to the field before the compass's distortion, the unit is held still
while the load's input is on, and :class:`BatteryReporter` tells PX4 the current as its power module would,
in BATTERY_STATUS from another component of the vehicle's system (PX4's SITL has no current-proportional
magnetometer term and its simulated battery reports −1 A: start it with ``SIM_BAT_ENABLE = 0``).  A right
compensation writes ``CAL_MAG_COMP_TYP = 2`` and ``CAL_MAGn_xCOMP = −10·k`` (G/kA) for the raw field change
``k = S⁻¹·R_mount⁻¹·c`` µT/A.

    python -m magline.sitl.px4_hil --truth truth.json [--port 4560] [--speed 0.5] [--seed 1]
"""

from __future__ import annotations

import argparse
import json
import socket
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from pymavlink.dialects.v20 import common as mavlink
from scipy.spatial.transform import Rotation

from magline.sim.truth.attitudes import spiral_attitude
from magline.sim.truth.sensor import earth_field_ned
from magline.sitl.held_clock import HeldClock

HIL_PORT = 4560  # PX4's simulator_mavlink connects here (+ its instance)
SENSOR_HZ = 250.0  # accelerometer and gyro, as PX4's own simulators send them
MAG_EVERY = 2  # the magnetometer in every second message: 125 Hz
GPS_EVERY = 25  # HIL_GPS at 10 Hz
GRAVITY_MSS = 9.80665
UT_PER_GAUSS = 100.0
# HIL_SENSOR.fields_updated: PX4's SensorSource bits (accelerometer, gyro, magnetometer, barometer)
ACCEL, GYRO, MAG = 0b111, 0b111000, 0b111000000
BARO = 0b1101000000000


@dataclass
class Px4Truth:
    """A compass's distortion in its own axes (µT; ``b = S·(m − h)``, ``S`` symmetric as PX4 holds it),
    the yaw it is really mounted at against the body (0: where the firmware expects it), and the site."""

    hard_iron_ut: list[float]
    soft_iron: list[list[float]]
    mounting_yaw_deg: float = 0.0
    field_ut: float = 48.0
    inclination_deg: float = 62.0
    latitude_deg: float = 47.3769
    longitude_deg: float = 8.5417
    altitude_m: float = 408.0
    noise_ut: float = 0.2
    speed: float = 0.5
    still_s: float = 8.0  # held level first: PX4's estimator and its sensors' checks settle on a still unit
    interference_ut_per_a: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])  # body axes
    expected: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        s = np.asarray(self.soft_iron, float)
        off = np.asarray(self.hard_iron_ut, float) / UT_PER_GAUSS
        self.expected = {**{f"{a}OFF": float(v) for a, v in zip("XYZ", off, strict=True)},
                         **{f"{a}SCALE": float(v) for a, v in zip("XYZ", np.diag(s), strict=True)},
                         "XODIAG": float(s[0, 1]), "YODIAG": float(s[0, 2]), "ZODIAG": float(s[1, 2])}

    @classmethod
    def drawn(cls, seed: int, **changes) -> Px4Truth:
        """A plausible board compass: offsets up to ±60 µT, a symmetric soft iron within ±6 % on the
        diagonal and ±2 % off it."""
        rng = np.random.default_rng(seed)
        diag = np.exp(rng.uniform(-0.06, 0.06, 3))
        s = np.diag(diag)
        s[0, 1], s[0, 2], s[1, 2] = rng.uniform(-0.02, 0.02, 3)
        s = np.triu(s) + np.triu(s, 1).T
        return cls(hard_iron_ut=rng.uniform(-60, 60, 3).round(2).tolist(), soft_iron=s.round(4).tolist(),
                   **changes)

    def expected_compensation(self) -> dict[str, float]:
        """``COMP_TYP`` and the ``xCOMP`` (G/kA) a right current compensation writes: minus the raw field
        change per amp, in the sensor's axes, in mG."""
        per_amp_body = np.asarray(self.interference_ut_per_a, float)
        raw = np.linalg.solve(np.asarray(self.soft_iron, float), self._body_to_sensor().apply(per_amp_body))
        return {"COMP_TYP": 2.0, **{f"{a}COMP": float(-10.0 * v) for a, v in zip("XYZ", raw, strict=True)}}

    def _body_to_sensor(self) -> Rotation:
        return Rotation.from_euler("z", self.mounting_yaw_deg, degrees=True).inv()

    def raw_gauss(self, body_to_ned: Rotation, rng: np.random.Generator, current_a: float = 0.0) -> NDArray:
        """What the compass reads (gauss, its own axes) with the unit in ``body_to_ned`` and ``current_a``
        through the board."""
        b_body = body_to_ned.inv().apply(earth_field_ned(self.field_ut, self.inclination_deg))
        b_body = b_body + current_a * np.asarray(self.interference_ut_per_a, float)
        b_sensor = self._body_to_sensor().apply(b_body)
        m = np.linalg.solve(np.asarray(self.soft_iron, float), b_sensor) + np.asarray(self.hard_iron_ut)
        return (m + rng.normal(scale=self.noise_ut, size=3)) / UT_PER_GAUSS


def attitude(truth: Px4Truth, t_s: float) -> Rotation:
    """Body → NED at motion time ``t_s``: still and level, then the tumble."""
    return Rotation.identity() if t_s < truth.still_s else spiral_attitude(truth.speed * (t_s - truth.still_s))


def hil_sensor(truth: Px4Truth, t_s: float, board_us: int, with_mag: bool, rng: np.random.Generator,
               dt_s: float = 1.0 / SENSOR_HZ, moving: bool = True, current_a: float = 0.0) -> dict[str, float | int]:
    """HIL_SENSOR's fields with the unit at motion time ``t_s`` and the board's clock at ``board_us``;
    ``moving=False``: the unit rests in the attitude of ``t_s``; ``current_a`` through the board."""
    now = attitude(truth, t_s)
    later = attitude(truth, t_s + dt_s) if moving else now
    rate = (now.inv() * later).as_rotvec() / dt_s  # body rates, rad/s: the body turns by its own
    force = now.inv().apply([0.0, 0.0, -GRAVITY_MSS])  # at rest level: −g on Z (forward-right-down)
    mag = truth.raw_gauss(now, rng, current_a) if with_mag else np.zeros(3)
    pressure_hpa = 1013.25 * (1.0 - 2.25577e-5 * truth.altitude_m) ** 5.25588
    return {"time_usec": board_us, "xacc": force[0], "yacc": force[1], "zacc": force[2],
            "xgyro": rate[0], "ygyro": rate[1], "zgyro": rate[2], "xmag": mag[0], "ymag": mag[1], "zmag": mag[2],
            "abs_pressure": pressure_hpa, "diff_pressure": 0.0, "pressure_alt": truth.altitude_m,
            "temperature": 25.0, "fields_updated": ACCEL | GYRO | BARO | (MAG if with_mag else 0), "id": 0}


class HilFeeder:
    """Serves PX4's simulator connection: HIL_SENSOR at :data:`SENSOR_HZ`, HIL_GPS at 10 Hz; what PX4
    sends (actuator outputs, heartbeats) is read and dropped.  One PX4 at a time; a new connection (the
    board powered again) replaces the old one.  :meth:`rest` sets the unit down where it is (as an operator
    does when the station says the tumble is done)."""

    def __init__(self, truth: Px4Truth, port: int = HIL_PORT, seed: int = 0,
                 current_a: Callable[[], float] = lambda: 0.0, held: Callable[[], bool] = lambda: False) -> None:
        self.truth = truth
        self.current_a, self.held = current_a, held
        self.clock = HeldClock()
        self.rng = np.random.default_rng(seed)
        self.server = socket.create_server(("127.0.0.1", port))
        self.server.settimeout(0.2)
        self.mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=mavlink.MAV_COMP_ID_USER1)
        self.stopped = threading.Event()
        self.closed = threading.Event()
        self.connections = 0
        self.started: float | None = None  # when the motion began (the first serve)
        self.rested_at: float | None = None  # the motion time the unit was set down at

    def motion_time(self, started: float) -> tuple[float, bool]:
        """The motion time now, and whether the unit still moves (not while it is held for a sweep)."""
        if self.rested_at is not None:
            return self.rested_at, False
        held = self.held()
        return self.clock.motion_s(started, time.monotonic(), held), not held

    def rest(self) -> None:
        """Set the unit down in the attitude it has now; it stays there (across power cuts too)."""
        if self.rested_at is None and self.started is not None:
            self.rested_at = self.clock.motion_s(self.started, time.monotonic(), self.held())

    def _drain(self, conn: socket.socket) -> None:
        conn.settimeout(0.5)
        while not self.stopped.is_set():
            try:
                if not conn.recv(4096):
                    return
            except TimeoutError:
                continue
            except OSError:
                return

    def _feed(self, conn: socket.socket, started: float) -> None:
        """Feed one PX4 process until it goes (a power cut) or the feeder stops."""
        threading.Thread(target=self._drain, args=(conn,), daemon=True).start()
        period, booted, n = 1.0 / SENSOR_HZ, time.monotonic(), 0
        truth = site = self.truth
        while not self.stopped.is_set():
            due = booted + n * period
            wait = due - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            board_us = int(n * period * 1e6) + 1
            t_s, moving = self.motion_time(started)
            fields = hil_sensor(truth, t_s, board_us, n % MAG_EVERY == 0, self.rng, moving=moving,
                                current_a=float(self.current_a()))
            frames = [self.mav.hil_sensor_encode(**fields).pack(self.mav)]
            if n % GPS_EVERY == 0:
                frames.append(self.mav.hil_gps_encode(
                    board_us, 3, int(site.latitude_deg * 1e7), int(site.longitude_deg * 1e7),
                    int(site.altitude_m * 1000), 100, 100, 0, 0, 0, 0, 65535, 12).pack(self.mav))
            try:
                conn.sendall(b"".join(frames))
            except OSError:
                return
            n += 1

    def serve(self) -> None:
        """Accept PX4 (again after each power cut) until :meth:`stop`; the motion's clock starts now."""
        started = self.started = time.monotonic()
        while not self.stopped.is_set():
            try:
                conn, _ = self.server.accept()
            except TimeoutError:
                continue
            except OSError:
                break
            self.connections += 1
            with conn:
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                self._feed(conn, started)
        self.server.close()
        self.closed.set()

    def stop(self, timeout_s: float = 2.0) -> None:
        """Stop feeding and free the port."""
        self.stopped.set()
        self.closed.wait(timeout_s)


class BatteryReporter:
    """The power module's word to PX4: BATTERY_STATUS with ``current_a()`` ten times a second, from another
    component of the vehicle's system (``mavlink_receiver`` takes no other), to one of PX4's MAVLink UDP
    ports; PX4 publishes it as battery_status instance 0, what ``CAL_MAG_COMP_TYP = 2`` multiplies by."""

    def __init__(self, current_a: Callable[[], float], port: int = 14580, volts: float = 16.8) -> None:
        self.current_a, self.address, self.volts = current_a, ("127.0.0.1", port), volts
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=mavlink.MAV_COMP_ID_BATTERY)
        self.stopped = threading.Event()
        self.thread = threading.Thread(target=self._send, name="BatteryReporter", daemon=True)

    def frame(self) -> bytes:
        """A full four-cell pack.  Why the charge is sent: PX4 takes ``battery_remaining`` as it comes, and
        "unknown" (−1) reads as −1 % — a dangerously low battery its commander shuts the system down for
        within a minute, and meanwhile it left the station's save (PREFLIGHT_STORAGE) unanswered."""
        cells = [round(self.volts * 1000 / 4)] * 4 + [65535] * 6
        return self.mav.battery_status_encode(
            0, mavlink.MAV_BATTERY_FUNCTION_ALL, mavlink.MAV_BATTERY_TYPE_LIPO, 2500, cells,
            round(float(self.current_a()) * 100.0), -1, -1, 100).pack(self.mav)

    def _send(self) -> None:
        while not self.stopped.wait(0.1):
            try:
                self.sock.sendto(self.frame(), self.address)
            except OSError:
                continue

    def start(self) -> BatteryReporter:
        self.thread.start()
        return self

    def stop(self) -> None:
        self.stopped.set()
        self.thread.join(timeout=2.0)
        self.sock.close()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m magline.sitl.px4_hil", description=__doc__.split("\n")[0])
    parser.add_argument("--truth", type=Path, required=True, help="where the truth is written (JSON)")
    parser.add_argument("--port", type=int, default=HIL_PORT)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--speed", type=float, default=0.5, help="the tumble's speed (1: 8 s pole to pole)")
    parser.add_argument("--mounting-yaw", type=float, default=0.0, help="the compass's true yaw on the body (°)")
    args = parser.parse_args(argv)
    truth = Px4Truth.drawn(args.seed, speed=args.speed, mounting_yaw_deg=args.mounting_yaw)
    args.truth.write_text(json.dumps(asdict(truth), indent=2) + "\n")
    feeder = HilFeeder(truth, args.port, seed=args.seed)
    print(f"HIL feeder on tcp:127.0.0.1:{args.port}, truth in {args.truth}", flush=True)
    try:
        feeder.serve()
    except KeyboardInterrupt:
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
