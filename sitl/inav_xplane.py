"""An X-Plane-protocol peer for INAV's SITL (``SITL.elf --sim=xp``) that tumbles a compass of known truth.

INAV's SITL asks its simulator for data references over UDP (``target/SITL/sim/xplane.c``): it sends
``RREF`` requests (frequency, its own index, the reference's name) and expects ``RREF`` packets back, each a
list of (index, float) pairs; with ``inav_xitl/plugin/xitlDrefVersion`` ≥ 2 it also takes the magnetometer
(``inav_xitl/sensors/magnetometer[0..2]``, gauss: the fake driver's counts are gauss·1024) and the battery.
Its main loop runs once per packet it receives, so the peer sends at a steady rate.

What the peer sends, in X-Plane's own conventions (so that what INAV makes of them is INAV's doing):
attitude ``phi``/``theta``/``psi`` (roll, pitch, heading, degrees), body rates ``P``/``Q``/``R`` (°/s,
forward-right-down), load factors ``g_axil``/``g_side``/``g_nrml`` (g; INAV's fake accelerometer takes
``(−axil, side, nrml)``, so ``g_nrml`` is +1 level), and the magnetometer in the compass's own axes:
the field of the station's site turned into the unit's body, into INAV's body axes (forward-left-up) and
back through the compass's alignment, then distorted by the truth (``m = S⁻¹·b + h``, in those axes).

The truth (a JSON file beside the run) holds the distortion, the alignment the compass really sits at,
the field, and the settings a right calibration writes: ``magzero = 1024·h`` counts and ``maggain =
1024·B / S_ii`` (INAV maps the field to 1024 counts).  With ``--useimu`` INAV's own estimator runs on what
the peer sends, and its attitude (``MSP_ATTITUDE``) can be held to the peer's: the check that the peer's
axes are INAV's.

    python -m magline.sitl.inav_xplane --truth truth.json [--port 49000] [--speed 0.5] [--seed 1]
"""

from __future__ import annotations

import argparse
import json
import socket
import struct
import sys
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from magline.core.links.msp import INAV_ALIGNMENTS, INAV_COMPASS_DEFAULT_ALIGNMENT, INAV_TO_FRD
from magline.sim.truth.attitudes import spiral_attitude
from magline.sim.truth.sensor import earth_field_ned

XPLANE_PORT = 49000  # INAV's default (XP_PORT)
COUNTS_PER_GAUSS = 1024.0  # INAV's fake magnetometer: fakeMagSet(gauss · 1024)
XITL_VERSION = 2.0  # INAV reads the magnetometer and battery only from this version on
GRAVITY_G = np.array([0.0, 0.0, 1.0])  # gravity in NED, in g


@dataclass
class InavTruth:
    """A compass's distortion in INAV's sensor axes (µT; ``m = S⁻¹·b + h``), the alignment it really sits
    at (an ``align_mag`` value), and the site's field."""

    hard_iron_ut: list[float]
    soft_iron_diag: list[float]
    alignment: int = INAV_COMPASS_DEFAULT_ALIGNMENT
    field_ut: float = 48.0
    inclination_deg: float = 62.0
    noise_ut: float = 0.2
    speed: float = 0.5
    still_s: float = 5.0  # held level, nose north, first: INAV calibrates its gyro at boot on a still unit
    poses: list[list[float]] = field(default_factory=list)  # held (heading, pitch, roll) in turn, not a tumble
    hold_s: float = 20.0  # each pose's time
    battery_current_a: float = 0.0
    expected: dict[str, int] = field(default_factory=dict)

    def __post_init__(self) -> None:
        c = COUNTS_PER_GAUSS / 100.0
        zero = np.round(np.asarray(self.hard_iron_ut) * c).astype(int)
        gain = np.round(c * self.field_ut / np.asarray(self.soft_iron_diag)).astype(int)
        self.expected = {**{f"magzero_{a}": int(v) for a, v in zip("xyz", zero, strict=True)},
                         **{f"maggain_{a}": int(v) for a, v in zip("xyz", gain, strict=True)},
                         "align_mag": int(self.alignment)}

    @classmethod
    def drawn(cls, seed: int, **changes) -> InavTruth:
        """A plausible board compass: offsets up to ±60 µT, gains within ±6 %."""
        rng = np.random.default_rng(seed)
        return cls(hard_iron_ut=rng.uniform(-60, 60, 3).round(2).tolist(),
                   soft_iron_diag=np.exp(rng.uniform(-0.06, 0.06, 3)).round(4).tolist(), **changes)

    def raw_gauss(self, body_to_ned: Rotation, rng: np.random.Generator) -> NDArray:
        """What the compass reads (gauss, its own axes) with the unit in ``body_to_ned``."""
        b_frd = body_to_ned.inv().apply(earth_field_ned(self.field_ut, self.inclination_deg))
        b_inav_body = np.array(INAV_TO_FRD, float) @ b_frd
        sensor = np.array(INAV_ALIGNMENTS[self.alignment], float).T @ b_inav_body
        m = sensor / np.asarray(self.soft_iron_diag) + np.asarray(self.hard_iron_ut)
        return (m + rng.normal(scale=self.noise_ut, size=3)) / 100.0


def attitude(truth: InavTruth, t_s: float) -> Rotation:
    """Body → NED at ``t_s`` after the peer's first answer: still, then the poses or the tumble."""
    if t_s < truth.still_s:
        return Rotation.identity()
    t_s -= truth.still_s
    if truth.poses:
        pose = truth.poses[min(int(t_s // truth.hold_s), len(truth.poses) - 1)]
        return Rotation.from_euler("ZYX", pose, degrees=True)
    return spiral_attitude(truth.speed * t_s)


def xplane_values(truth: InavTruth, t_s: float, rng: np.random.Generator, dt_s: float = 0.005) -> dict[str, float]:
    """Every data reference INAV asks for, by name, with the unit at motion time ``t_s``."""
    now, later = attitude(truth, t_s), attitude(truth, t_s + dt_s)
    rate_frd = np.degrees((now.inv() * later).as_rotvec() / dt_s)  # body rates: the body turns by its own
    specific_force = -now.inv().apply(GRAVITY_G)  # at rest: up, −1 g on Z (forward-right-down)
    heading, pitch, roll = now.as_euler("ZYX", degrees=True)
    mag = truth.raw_gauss(now, rng)
    return {
        "inav_xitl/plugin/xitlDrefVersion": XITL_VERSION,
        "sim/flightmodel/position/phi": roll, "sim/flightmodel/position/theta": pitch,
        "sim/flightmodel/position/psi": heading % 360.0, "sim/flightmodel/position/hpath": heading % 360.0,
        "sim/flightmodel/forces/g_axil": -specific_force[0], "sim/flightmodel/forces/g_side": -specific_force[1],
        "sim/flightmodel/forces/g_nrml": -specific_force[2],
        "sim/flightmodel/position/P": rate_frd[0], "sim/flightmodel/position/Q": rate_frd[1],
        "sim/flightmodel/position/R": rate_frd[2],
        "sim/weather/barometer_current_inhg": 29.92,
        "inav_xitl/sensors/magnetometer[0]": mag[0], "inav_xitl/sensors/magnetometer[1]": mag[1],
        "inav_xitl/sensors/magnetometer[2]": mag[2],
        "inav_xitl/sensors/battery_voltage": 12.6, "inav_xitl/sensors/battery_current": truth.battery_current_a,
        "inav_xitl/sensors/rangefinder": -1.0, "inav_xitl/gps/numSats": 0.0, "inav_xitl/gps/fix_type": 0.0,
        "inav_xitl/rc/rssi": 0.0, "inav_xitl/rc/failsafe": 0.0,
    }


def parse_rref_request(packet: bytes) -> tuple[int, int, str] | None:
    """INAV's ``registerDref``: ``RREF\\0``, frequency (u32), its index (u32), the name (NUL-ended)."""
    if len(packet) < 14 or packet[:5] != b"RREF\0":
        return None
    frequency, index = struct.unpack_from("<II", packet, 5)
    return frequency, index, packet[13:].split(b"\0", 1)[0].decode("ascii", "replace")


def rref_packet(pairs: list[tuple[int, float]]) -> bytes:
    """What X-Plane answers: ``RREF`` and a byte, then (index u32, value f32) pairs."""
    return b"RREF\0" + b"".join(struct.pack("<If", index, value) for index, value in pairs)


class XPlanePeer:
    """The peer: learns what INAV asks for from its requests and answers ``rate_hz`` times a second."""

    def __init__(self, truth: InavTruth, port: int = XPLANE_PORT, rate_hz: float = 200.0, seed: int = 0) -> None:
        self.truth = truth
        self.rate_hz = rate_hz
        self.rng = np.random.default_rng(seed)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", port))
        self.sock.settimeout(0.2)
        self.asked: dict[str, int] = {}  # reference name → INAV's index, for those asked at a frequency > 0
        self.inav: tuple[str, int] | None = None
        self.stopped = threading.Event()
        self.closed = threading.Event()

    def _listen(self) -> None:
        while not self.stopped.is_set():
            try:
                packet, sender = self.sock.recvfrom(2048)
            except TimeoutError:
                continue
            except OSError:
                return
            self.inav = sender
            request = parse_rref_request(packet)
            if request is not None:
                frequency, index, name = request
                if frequency:
                    self.asked[name] = index
                else:
                    self.asked.pop(name, None)

    def serve(self) -> None:
        """Answer until :meth:`stop` (or for ever); the motion's clock starts at the first answer."""
        listener = threading.Thread(target=self._listen, daemon=True)
        listener.start()
        period, due, first = 1.0 / self.rate_hz, time.monotonic(), None
        while not self.stopped.is_set():
            now = time.monotonic()
            if now < due:
                time.sleep(due - now)
            due = max(due + period, time.monotonic() - period)
            if self.inav is None or not self.asked:
                continue
            first = time.monotonic() if first is None else first
            values = xplane_values(self.truth, time.monotonic() - first, self.rng)
            pairs = [(index, float(values.get(name, 0.0))) for name, index in list(self.asked.items())]
            for start in range(0, len(pairs), 100):  # INAV reads 1,024 bytes a packet
                self.sock.sendto(rref_packet(pairs[start:start + 100]), self.inav)
        listener.join()
        self.sock.close()
        self.closed.set()

    def stop(self, timeout_s: float = 2.0) -> None:
        """Stop serving and free the port (a next peer can bind it at once)."""
        self.stopped.set()
        self.closed.wait(timeout_s)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m magline.sitl.inav_xplane", description=__doc__.split("\n")[0])
    parser.add_argument("--truth", type=Path, required=True, help="where the truth is written (JSON)")
    parser.add_argument("--port", type=int, default=XPLANE_PORT)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--speed", type=float, default=0.5, help="the tumble's speed (1: 8 s pole to pole)")
    parser.add_argument("--alignment", type=int, default=INAV_COMPASS_DEFAULT_ALIGNMENT,
                        help="the align_mag value the compass really sits at (INAV's DEFAULT: 8, CW270FLIP)")
    args = parser.parse_args(argv)
    truth = InavTruth.drawn(args.seed, speed=args.speed, alignment=args.alignment)
    args.truth.write_text(json.dumps(asdict(truth), indent=2) + "\n")
    peer = XPlanePeer(truth, args.port, seed=args.seed)
    print(f"X-Plane peer on udp:127.0.0.1:{args.port}, truth in {args.truth}", flush=True)
    try:
        peer.serve()
    except KeyboardInterrupt:
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
