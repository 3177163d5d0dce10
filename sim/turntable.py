"""A simulated turntable rig (the stage controller ``plugins/turntable`` drives), its cradle, and the
operator who tilts the cradle when the rig's pendant asks.

The table turns about the vertical at its speed for the revolutions asked; the cradle on it holds the
units at the tilt the operator set (body → table: pitch then roll, FRD).  Simulated flight controllers
mounted on it (``magline sim px4|ardupilot|inav --turntable ADDRESS``) ask ``ATT?`` every
``FOLLOW_S`` and compute the attitude locally, so several boards on one table see the same turn: the
answer is the turn and the cradle's move as functions of time, and a board sends a reading only once it
knows how the table moved at the reading's instant (``MotionFollower.horizon``).

The simulated operator reads the tilt asked on the pendant (``DISP:TILT``) and sets it after a reaction
time, moving the cradle for ``MOVE_S``; ``operator="wrong"`` first sets a wrong tilt (nose and tail
swapped) and corrects it once the pendant names it, ``"never"`` never touches the cradle.  Faults:
``not_homed`` (the home switch is never found), ``not_turning`` (the table is asked to turn and never
does), ``stalls`` (it turns once, then stalls: something blocks it mid-batch), ``lost_link`` (the
controller stops answering once the second turn began: the first is the station's spin check).
"""

from __future__ import annotations

import re
import threading
import time

from scipy.spatial.transform import Rotation, Slerp

from magline.sim.scpi_server import ScpiServer

OPERATORS = ("follow", "wrong", "never")
FAULTS = ("not_homed", "not_turning", "stalls", "lost_link")
MOVE_S = 0.4  # the operator's hands moving the cradle from one tilt to the next
HOME_S = 0.3  # the stage's homing run


def cradle_rotation(pitch_deg: float, roll_deg: float) -> Rotation:
    """Body → table for a cradle tilt (the same convention the station asks in)."""
    return Rotation.from_euler("ZYX", [0.0, pitch_deg, roll_deg], degrees=True)


def cradle_moving(start: Rotation, to: Rotation, since: float, seconds: float, wall: float) -> Rotation:
    """The cradle at ``wall`` while the operator moves it from ``start`` to ``to`` over ``seconds`` from
    ``since``: the table's own state and what a board in the cradle computes from ``ATT?`` alike."""
    span = (wall - since) / seconds
    if span >= 1.0:
        return to
    return Slerp([0.0, 1.0], Rotation.concatenate([start, to]))([max(span, 0.0)])[0]


def turned_angle(angle0: float, t0: float, speed_dps: float, until: float, wall: float) -> float:
    """The table's angle at ``wall`` during a turn from ``angle0`` at ``t0`` until ``until`` (``speed_dps``
    signed by direction): the table's own state and what a board computes from ``ATT?`` alike.  Before
    ``t0`` the table stood at ``angle0`` — a board late to compute an instant from just before a turn it
    had already learnt of ran the turn backwards to it."""
    return angle0 + speed_dps * (min(max(wall, t0), until) - t0) if until > t0 else angle0


class TurntableSim(ScpiServer):
    identity = "magline,SIM-TURNTABLE,0001,1.0"

    def __init__(self, listen: str = "tcp:127.0.0.1:5050", operator: str = "follow", reaction_s: float = 0.5,
                 fault: str | None = None, homed: bool = False) -> None:
        super().__init__(listen)
        if operator not in OPERATORS:
            raise ValueError(f"unknown operator {operator!r}; choose from {', '.join(OPERATORS)}")
        if fault is not None and fault not in FAULTS:
            raise ValueError(f"unknown turntable fault {fault!r}; choose from {', '.join(FAULTS)}")
        self.operator, self.reaction_s, self.fault = operator, reaction_s, fault
        self.homed, self._homing_until = homed, None
        self.speed_dps, self.direction = 60.0, 1.0
        self.angle0, self.t0, self.until = 0.0, 0.0, 0.0  # the turn under way: from angle0 at t0 (wall) to until
        self.turns = 0  # revolutions started (a slot test counts the shared turns)
        self.display, self.asked = "", None  # the pendant's words and target tilt (pitch, roll)
        self._from = self._to = cradle_rotation(0.0, 0.0)
        self._move_t0 = 0.0
        self.tilts_set: list[tuple[float, float]] = []  # every tilt the operator made, in order
        self._wrong_done = False
        self._stop_operator = threading.Event()
        self._operator = threading.Thread(target=self._operate, name="sim-turntable-operator", daemon=True)

    def start(self) -> TurntableSim:
        super().start()
        self._operator.start()
        return self

    def stop(self) -> None:
        self._stop_operator.set()
        super().stop()

    # ------------------------------------------------------------------ the table and the cradle
    def angle_at(self, wall: float) -> float:
        with self.lock:
            return turned_angle(self.angle0, self.t0, self.direction * self.speed_dps, self.until, wall)

    def stalled(self) -> bool:
        return self.fault == "not_turning" or (self.fault == "stalls" and self.turns > 1)

    def moving(self, wall: float) -> bool:
        return self.until > wall and not self.stalled()

    def cradle(self, wall: float) -> Rotation:
        with self.lock:
            return cradle_moving(self._from, self._to, self._move_t0, MOVE_S, wall)

    def attitude(self, wall: float | None = None) -> Rotation:
        """The units' attitude (body → NED): the table's turn, then the cradle's tilt."""
        wall = time.time() if wall is None else wall
        return Rotation.from_euler("Z", self.angle_at(wall), degrees=True) * self.cradle(wall)

    def set_tilt(self, pitch_deg: float, roll_deg: float) -> None:
        """The operator moves the cradle to this tilt (over ``MOVE_S``).

        The move's start is read under the lock: read before it, a thread held back on a loaded machine
        dated the move before an ``ATT?`` answered meanwhile, and the boards that had sent the cradle
        standing still for those instants were proven wrong after the fact (a good unit FAILed its
        mounting at 3–10°)."""
        with self.lock:
            now = time.time()
            self._from, self._to, self._move_t0 = self.cradle(now), cradle_rotation(pitch_deg, roll_deg), now
            self.tilts_set.append((pitch_deg, roll_deg))

    # ------------------------------------------------------------------ SCPI
    def command(self, head: str, arg: str) -> str | None:
        now = time.time()
        if self._homing_until is not None and now >= self._homing_until:
            self.homed, self._homing_until = True, None
        if head == "HOME":
            if self.fault == "not_homed":
                self.errors.append('-240,"Hardware error; home switch not found"')
            else:
                self._homing_until = now + HOME_S
            return None
        if head == "HOME?":
            return "1" if self.homed else "0"
        if head in ("ROT:SPE", "ROT:SPEED"):
            self.speed_dps = float(arg)
            return None
        if head in ("ROT:DIR", "ROT:DIRECTION"):
            if arg.upper() not in ("CW", "CCW"):
                raise ValueError(arg)
            self.direction = 1.0 if arg.upper() == "CW" else -1.0
            return None
        if head == "ROT:TURN":
            if not self.homed:
                self.errors.append('-221,"Settings conflict; not homed"')
                return None
            revolutions = float(arg or 1)
            self.angle0, self.t0 = self.angle_at(now), now
            self.turns += 1
            self.until = now if self.stalled() else now + 360.0 * revolutions / self.speed_dps
            if self.fault == "lost_link" and self.turns > 1:
                self.silent = True  # the controller stops answering mid-turn (its cable pulled)
            return None
        if head == "ROT:STOP":
            self.angle0, self.t0, self.until = self.angle_at(now), now, now
            return None
        if head == "ROT:STAT?":
            # the position is the stage's own count, cumulative (not taken modulo a revolution)
            if self.stalled():
                return f"MOVING,{self.angle_at(now):.2f},0"
            moving = self.moving(now)
            return (f"MOVING,{self.angle_at(now):.2f},{self.speed_dps:g}" if moving
                    else f"IDLE,{self.angle_at(now):.2f},0")
        if head == "DISP:TEXT":
            self.display = arg.strip().strip('"')
            return None
        if head == "DISP:TILT":
            pitch, roll = (float(v) for v in arg.split(","))
            self.asked = (pitch, roll)
            return None
        if head == "ATT?":  # for the boards on the table: the turn's and the cradle's move's parameters
            with self.lock:
                turn = f"{self.t0:.6f},{self.angle0:.4f},{self.direction * self.speed_dps:g},{self.until:.6f}"
                to, start, since = self._to.as_quat(), self._from.as_quat(), self._move_t0
            return (f"TURN,{turn}," + ",".join(f"{v:.9f}" for v in to) + f",{since:.6f},{MOVE_S:g},"
                    + ",".join(f"{v:.9f}" for v in start))
        raise KeyError(head)

    # ------------------------------------------------------------------ the simulated operator
    def _operate(self) -> None:
        handled: tuple[float, float] = (0.0, 0.0)  # the tilt last acted on (the unit is loaded level)
        wrong = False  # the cradle is in the wrong tilt this operator set on purpose
        while not self._stop_operator.wait(0.05):
            with self.lock:
                asked, display = self.asked, self.display
            if asked is None or self.operator == "never":
                continue
            named = bool(re.match(r"The cradle is .*, not ", display))  # the pendant names a wrong tilt
            if asked == handled and not (wrong and named):
                continue
            if self._stop_operator.wait(self.reaction_s):
                return
            pitch, roll = asked
            if self.operator == "wrong" and not self._wrong_done and asked != (0.0, 0.0):
                self._wrong_done = wrong = True
                pitch, roll = (-pitch, roll) if pitch else (pitch, roll + 180.0)  # nose and tail, or sides, mixed up
            else:
                wrong = False
            self.set_tilt(pitch, roll)
            handled = asked
