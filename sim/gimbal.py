"""A simulated motorised gimbal (the controller ``plugins/gimbal`` drives) and the follower that lets
simulated flight controllers mounted on it feel its motion.

Why a separate simulator: on a slot station the units share one motion.  Each simulated flight
controller given ``motion_source`` asks the gimbal what it is doing (``PATT?``, every
``FOLLOW_S``) and turns the Earth field into its body frame with the gimbal's attitude: the same
pattern function, started at the same wall-clock time, so four boards on one gimbal see the same
orientations at the same moment, as on the line.
"""

from __future__ import annotations

import socket
import threading
import time

import numpy as np
from scipy.spatial.transform import Rotation

from magline.sim.magnetometers import attitude
from magline.sim.scpi_server import ScpiServer
from magline.sim.transport import parse_peer
from magline.sim.turntable import cradle_moving, turned_angle

PATTERNS = ("TUMBLE", "GIMBAL")
FOLLOW_S = 0.05
ANSWER_TIMEOUT_S = 10.0  # a fixture that answers nothing this long is lost (MotionFollower.horizon)


class GimbalSim(ScpiServer):
    identity = "magline,SIM-GIMBAL,0001,1.0"

    def __init__(self, listen: str = "tcp:127.0.0.1:5030") -> None:
        super().__init__(listen)
        self.pattern: str | None = None
        self.speed = 1.0
        self.t0 = 0.0
        self.held = Rotation.identity()
        self.starts = 0  # patterns started (a test counts the shared rounds)

    def attitude(self, at: float | None = None) -> Rotation:
        """The platform's attitude (body → NED) at wall-clock time ``at``."""
        with self.lock:
            if self.pattern is None:
                return self.held
            return attitude(self.pattern.lower(), (at or time.time()) - self.t0, self.speed)

    def command(self, head: str, arg: str) -> str | None:
        if head in ("PATT:STAR", "PATTERN:START"):
            name, _, speed = arg.partition(",")
            if name.strip().upper() not in PATTERNS:
                self.errors.append(f'-224,"Illegal parameter value; pattern {name.strip()[:20]}"')
                return None
            self.pattern, self.speed = name.strip().upper(), float(speed or 1.0)
            self.t0 = time.time()
            self.starts += 1
            return None
        if head in ("PATT:STOP", "PATTERN:STOP"):
            if self.pattern is not None:
                self.held = attitude(self.pattern.lower(), time.time() - self.t0, self.speed)
            self.pattern = None
            return None
        if head in ("PATT?", "PATTERN?"):
            if self.pattern is None:
                q = self.held.as_quat()
                return "IDLE," + ",".join(f"{v:.9f}" for v in q)
            return f"{self.pattern},{self.speed:g},{self.t0:.6f}"
        raise KeyError(head)


def _cos_sin_deg(angle_deg: float) -> tuple[float, float]:
    rad = np.deg2rad(angle_deg)
    return float(np.cos(rad)), float(np.sin(rad))


class MotionFollower:
    """A board's view of the fixture it is mounted on — a gimbal (``PATT?``) or a turntable with its
    cradle (``ATT?``, :mod:`magline.sim.turntable`), told apart by ``*IDN?`` — polled every ``FOLLOW_S``;
    the attitude is computed locally, so a board reads its sensors at its own rate without a round trip
    per reading."""

    def __init__(self, address: str) -> None:
        self.address = parse_peer(address, "the fixture's address")
        self._pattern: tuple[str, float, float] | None = None
        self._held = Rotation.identity()
        # a turntable: the turn (t0, angle0, °/s, until; wall-clock times) and the cradle's tilt, moving from a
        # tilt to the next over a few tenths of a second (move start, its seconds, from, to)
        self._turn: tuple[float, float, float, float, Rotation] | None = None
        self._move: tuple[float, float, Rotation, Rotation] | None = None
        self._cradle_matrix: tuple[Rotation, np.ndarray] | None = None  # the still cradle's matrix, worked out once
        # the monotonic time up to which the platform's motion is known: when the last answer was asked for
        self.known_until = float("-inf")
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._wall_minus_monotonic = time.time() - time.monotonic()  # the pattern's t0 is wall-clock time
        self.error: str | None = None
        self._thread = threading.Thread(target=self._follow, name="sim-gimbal-follower", daemon=True)
        self._thread.start()

    def attitude(self, at: float | None = None) -> Rotation:
        """The platform's attitude at ``at`` (this process's ``time.monotonic()``; now when None).

        Why an instant: a board stamps a message's magnetometer and accelerometer with one time, so
        both must be the attitude of that instant — evaluated at two call times instead, they were
        a fraction of a millisecond apart, which a fast pattern turned into a 2° false mounting error."""
        wall = time.time() if at is None else at + self._wall_minus_monotonic
        with self._lock:
            if self._turn is not None:
                t0, angle0, speed, until, cradle = self._turn
                angle = turned_angle(angle0, t0, speed, until, wall)
                if self._move is not None:  # the cradle where it was at that instant, not where it is now
                    since, seconds, start, cradle = self._move
                    cradle = cradle_moving(start, cradle, since, seconds, wall)
                return Rotation.from_euler("Z", angle, degrees=True) * cradle
            if self._pattern is None:
                return self._held
            name, speed, t0 = self._pattern
        return attitude(name.lower(), wall - t0, speed)

    def matrix(self, at: float) -> np.ndarray:
        """:meth:`attitude` at ``at`` as its matrix (body → NED), computed without scipy's ``Rotation``
        where the table turns a still cradle: a board asks it twice for each message it streams, and
        composing scipy's rotations took 100 µs a time where this takes 10 (a board on a turntable spent
        about 1 ms of a core on each message it streamed)."""
        wall = at + self._wall_minus_monotonic
        with self._lock:
            turn, move = self._turn, self._move
            if turn is not None and (move is None or wall >= move[0] + move[1]):
                t0, angle0, speed, until, cradle = turn
                c, s = _cos_sin_deg(turned_angle(angle0, t0, speed, until, wall))
                if self._cradle_matrix is None or self._cradle_matrix[0] is not cradle:
                    self._cradle_matrix = (cradle, cradle.as_matrix())
                return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ self._cradle_matrix[1]
        return self.attitude(at).as_matrix()

    def horizon(self, now: float) -> float:
        """The latest instant (monotonic) whose attitude is known: what the follower had asked before its
        last answer.  Why a board waits for it: a turn or a pattern learnt a poll late was, until then,
        computed as the motion before it — the readings already sent held the table still while it
        turned, then jumped by the turn's speed times the lag (a loaded machine's 0.4 s lag once made a
        good unit's mounting 54° and its skew −150 ms).  Messages wait for the knowledge instead, so they
        are late, never wrong — however late: a follower starved of the processor for over a second is still
        following (waiting only a second once gave a good unit on a turntable a 4.95° mounting and a +128 ms
        skew at load 8).  Only a follower that lost its fixture (no connection, no answer within its
        timeout, its thread ended) holds nothing back: there is no knowledge to wait for."""
        if self.error is not None or not self._thread.is_alive():
            return now
        return min(now, self.known_until)

    @property
    def speed(self) -> float:
        """The pattern's speed (1 while the gimbal holds still)."""
        with self._lock:
            return 1.0 if self._pattern is None else self._pattern[1]  # a turntable turns in real time

    def stop(self) -> None:
        self._stop.set()

    def _follow(self) -> None:
        while not self._stop.is_set():
            try:
                with socket.create_connection(self.address, timeout=2.0) as link, \
                        link.makefile("rw", encoding="ascii", newline="\n") as wire:
                    # an answer's wait: a fixture gone closes the connection at once; one slow to answer (a
                    # simulator starved on a loaded machine) is still there, and its boards wait for it
                    link.settimeout(ANSWER_TIMEOUT_S)
                    self.error = None
                    wire.write("*IDN?\n")
                    wire.flush()
                    query = "ATT?" if "TURNTABLE" in wire.readline().upper() else "PATT?"
                    while not self._stop.wait(FOLLOW_S):
                        asked = time.monotonic()
                        wire.write(query + "\n")
                        wire.flush()
                        self._update(wire.readline().strip())
                        self.known_until = asked
            except (OSError, ValueError) as exc:
                self.error = f"gimbal {self.address[0]}:{self.address[1]}: {exc}"
                self._stop.wait(0.5)
            except Exception as exc:  # an answer it cannot read: said, and no board waits for it any more
                self.error = f"gimbal {self.address[0]}:{self.address[1]}: {type(exc).__name__}: {exc}"
                raise

    def _update(self, answer: str) -> None:
        parts = answer.split(",")
        if not answer:
            raise ValueError("no answer")
        with self._lock:
            if parts[0] == "TURN":
                t0, angle0, speed, until = (float(v) for v in parts[1:5])
                self._turn = (t0, angle0, speed, until, Rotation.from_quat([float(v) for v in parts[5:9]]))
                if len(parts) >= 15:
                    start = Rotation.from_quat([float(v) for v in parts[11:15]])
                    self._move = (float(parts[9]), float(parts[10]), start, self._turn[4])
            elif parts[0] == "IDLE":
                self._pattern = None
                self._held = Rotation.from_quat(np.array([float(v) for v in parts[1:5]]))
            else:
                self._pattern = (parts[0], float(parts[1]), float(parts[2]))
