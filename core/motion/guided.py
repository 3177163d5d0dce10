"""The turntable's round: ask the operator for a tilt of the cradle, prove it with the accelerometer,
turn the table one revolution, choose the next tilt — until the acquisition ends (the stop rule says the
calibration is determined, or the operator never makes a tilt and the tumble stalls).

Why in the core and not in the turntable's plugin: the choice needs the run's coverage, each unit's
accelerometer and sensor mounting and the field's inclination, and the prompts go to the operator
through the run; the plugin only turns the table (:class:`~magline.core.motion.TurnsForTilts`).  One
guide serves every slot on the cradle (one round of :mod:`magline.core.sequencer.rounds`): each slot's
acquisition hands it what its unit sees, and the table turns when every unit agrees the tilt is made.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from magline.core.motion.tilts import COVERAGE_TILTS, Tilt, best_tilt, off_by_deg, tilt_of_gravity, vector_angle_deg

DEFAULT_INCLINATION_DEG = 60.0  # where no field reference says: the ring's placement is a heuristic
POLL_S = 0.1  # how often the table is asked whether its revolution is done (not at every chunk)
# A unit of the round not heard from yet holds the table this long at most: every slot of a round is about to hand
# its first readings over (its stream opening, seconds on a loaded station); one silent longer has failed, and its
# own stream timeout ends it, so it must not hold the others' tumble
FIRST_STEP_WAIT_S = 10.0


@dataclass
class Guidance:
    """What the station asks now: ``state`` is ``tilt`` (waiting for the operator), ``turning`` or
    ``stalled`` (``why`` says what is missing); ``prompt`` is set when the words to the operator change,
    for the slot that speaks for the cradle (``leader``)."""

    state: str
    tilt: Tilt
    step: int  # the how-many-th tilt of this round (1 first)
    prompt: str | None = None
    leader: str = ""
    found: Tilt | None = None  # what the accelerometer says the cradle is in, when it disagrees
    why: str = ""

    def to_dict(self) -> dict:
        return {"state": self.state, "asked": self.tilt.words, **self.tilt.picture(), "step": self.step,
                "found": self.found.words if self.found is not None else None, "why": self.why}


@dataclass
class _Seen:
    gravity: NDArray | None = None
    at: float = 0.0
    steady: bool = False
    covered: set[int] = field(default_factory=set)
    sensor_to_body: NDArray = field(default_factory=lambda: np.eye(3))
    at_ask: NDArray | None = None  # the gravity when the tilt was asked: a cradle not moved since is not "wrong"
    stepped: float = 0.0  # when the slot last handed its readings over (a slot whose tumble ended stops)
    board_ms: float | None = None  # the unit's clock at its latest reading
    # the station's clock less the unit's at the reading that arrived soonest after it was taken (ms): how the
    # two clocks stand, as an NTP client sets its offset by its fastest exchange
    offset_ms: float = float("inf")


class TiltGuide:
    """One round's guidance (thread-safe: each slot's acquisition calls :meth:`step`)."""

    def __init__(self, motion, members: list[str], n_bins: int, inclination_deg: float | None = None,
                 clock=time.monotonic) -> None:
        self.motion = motion
        self.members = list(members)
        self.n_bins = n_bins
        self.inclination_deg = DEFAULT_INCLINATION_DEG if inclination_deg is None else inclination_deg
        self.named: list[Tilt] = list(motion.tilts or [])
        self.tolerance_deg = float(motion.tolerance_deg)
        self.settle_s = float(motion.settle_s)
        self.tilt_timeout_s = float(motion.tilt_timeout_s)
        self.clock = clock
        self._lock = threading.Lock()
        self._seen: dict[str, _Seen] = {}
        self._ended: set[str] = set()  # members whose tumble is over (they no longer speak for the cradle)
        self._made_at = clock()
        self.done: list[Tilt] = []  # the tilts turned so far, in order
        self.turns = 0
        self._state = "tilt"
        self._tilt: Tilt | None = None
        self._asked_at = 0.0
        self._agree_since: float | None = None
        self._wrong_since: float | None = None
        self._said = ""
        self._polled = 0.0
        self._found: Tilt | None = None
        self._why = ""

    # ------------------------------------------------------------------ what a slot hands over
    def step(self, slot: str, gravity_mss: NDArray | None, steady: bool, covered: set[int],
             sensor_to_body: NDArray, board_ms: float | None = None) -> Guidance:
        """``gravity_mss``: the unit's latest specific force (None when its stream has none), ``steady``:
        whether it held still over the last readings; ``covered``: its coverage bins so far; ``board_ms``:
        the unit's own clock at its latest reading (None: the stream has none)."""
        now = self.clock()
        with self._lock:
            seen = self._seen.setdefault(slot, _Seen())
            seen.covered, seen.sensor_to_body, seen.stepped = set(covered), np.asarray(sensor_to_body, float), now
            if board_ms is not None:
                seen.board_ms = float(board_ms)
                seen.offset_ms = min(seen.offset_ms, now * 1000.0 - seen.board_ms)
            if gravity_mss is not None:
                seen.gravity, seen.at, seen.steady = np.asarray(gravity_mss, float), now, steady
            if self._tilt is None:  # the first tilt: the first slot says it at its first step, whoever asked
                self._ask(self._next_tilt(), now)
            # a next tilt only in the step of the slot that speaks for the cradle, so the words shown on the pendant
            # are in the speaker's record (one asked in another slot's step just before the speaker's tumble
            # ended was made by the operator and said nowhere)
            speaks = slot == self._leader(slot, now)
            if self._state == "tilt":
                self._check_tilt(now)
            elif self._state == "turning" and speaks and now - self._polled >= POLL_S:
                self._polled = now
                if not self.motion.turning():
                    self.done.append(self._tilt)
                    following = self._next_tilt()
                    if following is None:
                        self._stall(f"every tilt of the cradle was turned ({len(self.done)}) and the field has "
                                    "no direction left to show: the coverage target cannot be reached")
                    else:
                        self._ask(following, now)
            return self._guidance(slot, now)

    # ------------------------------------------------------------------ under the lock
    def _next_tilt(self) -> Tilt | None:
        if len(self.done) < len(self.named):
            return self.named[len(self.done)]
        if not self.done and not self.named:
            return Tilt(0.0, 0.0)  # the unit is loaded level: the first turn needs no hand on the cradle
        units = list(self._seen.values()) or [_Seen()]
        tilt, _ = best_tilt([t for t in COVERAGE_TILTS if t not in self.done], [u.covered for u in units],
                            self.inclination_deg, [u.sensor_to_body for u in units], self.n_bins)
        return tilt

    def _ask(self, tilt: Tilt, now: float) -> None:
        self._tilt, self._state, self._asked_at = tilt, "tilt", now
        self._agree_since = self._wrong_since = None
        self._found = None
        for seen in self._seen.values():
            seen.at_ask = seen.gravity
        self.motion.show(self._words(), tilt)

    def _check_tilt(self, now: float) -> None:
        fresh = [s for s in self._seen.values() if s.gravity is not None and now - s.at < 1.0]
        if not fresh:
            return
        if any(m not in self._seen for m in self.members) and now - self._made_at < FIRST_STEP_WAIT_S:
            # a unit not heard from yet would miss the turn: a CI run's slot A opened its stream after B had
            # seen the cradle level and the table turned for B alone (A lost that turn, and its record the words)
            self._agree_since = None
            return
        off = [off_by_deg(s.gravity, self._tilt) for s in fresh]
        if all(o <= self.tolerance_deg for o in off) and all(s.steady for s in fresh):
            self._wrong_since, self._found = None, None
            self._agree_since = self._agree_since if self._agree_since is not None else now
            if now - self._agree_since >= self.settle_s:
                self.motion.turn()
                self.turns += 1
                self._state, self._polled = "turning", now
            return
        self._agree_since = None
        worst = max(zip(off, fresh, strict=True), key=lambda pair: pair[0])[1]
        moved = worst.at_ask is None or vector_angle_deg(worst.gravity, worst.at_ask) > self.tolerance_deg
        if worst.steady and moved and max(off) > self.tolerance_deg:
            # moved since the ask and held still in another tilt: named once held for the settle time (a cradle
            # not yet touched is waited for, not called wrong before the operator had a chance)
            self._wrong_since = self._wrong_since if self._wrong_since is not None else now
            if now - self._wrong_since >= self.settle_s:
                found = tilt_of_gravity(worst.gravity)
                if found != self._found:
                    self._found = found
                    self.motion.show(self._words(), self._tilt)
        else:
            self._wrong_since = None
        if now - self._asked_at > self.tilt_timeout_s and all(self._taken_since_ask_s(s) > self.tilt_timeout_s
                                                               for s in fresh):
            self._stall(f"the cradle was never tilted {self._tilt.words} (asked {self.tilt_timeout_s:g} s ago)")

    def _taken_since_ask_s(self, seen: _Seen) -> float:
        """How long after the ask the unit's latest reading was taken, on its own clock (∞ without one).
        Why not the station's clock alone: a station that fell behind its streams (a loaded machine) judged
        readings taken seconds before, and called a cradle tilted in time "never tilted"."""
        if seen.board_ms is None or not np.isfinite(seen.offset_ms):
            return float("inf")
        return (seen.board_ms - (self._asked_at * 1000.0 - seen.offset_ms)) / 1000.0

    def _stall(self, why: str) -> None:
        self._state, self._why = "stalled", why

    def _guidance(self, slot: str, now: float) -> Guidance:
        # the first member still reading speaks for the cradle: one whose tumble ended hands it on; one that has
        # not stepped yet is about to (a CI run's second slot stepped first and took the first words from the first)
        leader = self._leader(slot, now)
        words = self._words()
        prompt = None
        if slot == leader and words != self._said:
            self._said = prompt = words
        return Guidance(state=self._state, tilt=self._tilt, step=len(self.done) + 1, prompt=prompt, leader=leader,
                        found=self._found, why=self._why)

    def leave(self, slot: str) -> None:
        """``slot``'s tumble ended: it no longer speaks for the cradle."""
        with self._lock:
            self._ended.add(slot)

    def _leader(self, slot: str, now: float) -> str:
        """The first member whose tumble has not ended.  Why not "stepped within the last second": under a
        loaded CI the first slot's readings came more than a second apart, the second slot took the words
        mid-tumble and its record said the first tilt again."""
        reading = [m for m in self.members if m not in self._ended]
        return reading[0] if reading else slot

    def _words(self) -> str:
        if self._state == "turning":
            return f"Hands off the cradle: the table turns ({self._tilt.words})"
        if self._state == "stalled":
            return self._why[:1].upper() + self._why[1:]
        if self._found is not None:
            return f"The cradle is {self._found.words}, not {self._tilt.words}: tilt it {self._tilt.words}"
        return f"Tilt the cradle: {self._tilt.words}"
