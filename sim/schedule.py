"""When a simulated board's periodic messages fall due: on the board's own clock, whatever the host did.

Why: a board samples, stamps and sends on its own timer; a host too loaded to run the simulator's loop
for 50 ms must change only when the bytes arrive, never what the board measured or the instant it
stamped.  The loop used to compute and stamp each message at the moment it happened to run, and to drop
what a stall had skipped: under a loaded CI run a 10 Hz compass read 8.3 Hz, a 50 Hz stream repeated
each reading 2.87 times instead of 5, and good units FAILed their mounting on timing no board has.

Each message still leaves within its scheduler's tick after its nominal instant (uniformly, up to
:data:`SCHEDULER_JITTER_S`), as the loop's own 2 ms poll placed it before: a stream's instants then fall
at every fraction of a millisecond, and the whole-millisecond stamps of two streams lose the same
fraction on average.  Without it each stream kept one constant fraction of its own, a relative skew
between two compasses that turned into a degree of disagreement on a fast tumble.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass

SCHEDULER_JITTER_S = 0.002  # a message goes out within this of its nominal instant (a board's scheduler tick)
# A stall longer than this (the host suspended) loses what fell due before its last this-many seconds.
# Why so long: a board samples whatever its host does, and a suite on two loaded cores stopped the
# simulator's loop for over a second (py-spy, sampling it, fell 3.8 s behind): dropped, a 10 Hz sensor
# read 7.2 Hz where the station measures the sensor's rate
CATCH_UP_S = 10.0
# How much of the board's time one call hands out, oldest first: a host too slow to compute the board's
# messages as fast as they fall due (load 8 on two cores, two boards in one process) once fell further
# behind with each call, every call computing all it had missed (0.7, 1.2, 2.1, 4.3 ... 14.7 s), and the
# loop sent its heartbeat and answered commands only between calls: the station saw no heartbeat for
# 2.5 s and called a live link lost.  Handed out a slice at a time, the loop goes round between slices.
SLICE_S = 0.05


@dataclass
class Periodic:
    """One periodic message: its interval, its next nominal instant and that instant with its jitter."""

    interval_s: float
    nominal_s: float
    due_s: float


class BoardSchedule:
    """The board's periodic messages by key (a message id), and the instants each fell due at."""

    def __init__(self, rng: random.Random) -> None:
        self.rng = rng
        self.streams: dict[int, Periodic] = {}

    def start(self, key: int, interval_s: float, at_s: float) -> None:
        self.streams[key] = Periodic(interval_s, at_s, at_s)  # the first one at once, as the command asks

    def stop(self, key: int) -> None:
        self.streams.pop(key, None)

    def clear(self) -> None:
        self.streams.clear()

    def __bool__(self) -> bool:
        return bool(self.streams)

    def next_due_s(self) -> float:
        """The instant the next message falls due (infinity when none runs)."""
        return min((stream.due_s for stream in self.streams.values()), default=math.inf)

    def due(self, now_s: float) -> list[tuple[float, int]]:
        """The (instant, key) pairs that fell due up to ``now_s``, oldest first across all streams: what the
        board sent while the host did not run the loop, each to be computed at its own instant — at most
        :data:`SLICE_S` of them past the oldest; the rest stay due for the next call."""
        due: list[tuple[float, int]] = []
        for stream in self.streams.values():
            behind = now_s - CATCH_UP_S - stream.nominal_s
            if behind > 0.0:  # the host stopped us for longer than a load does: resume CATCH_UP_S back
                stream.nominal_s += math.ceil(behind / stream.interval_s) * stream.interval_s
                stream.due_s = stream.nominal_s
        until_s = min(now_s, self.next_due_s() + SLICE_S)
        for key, stream in self.streams.items():
            while stream.due_s <= until_s:
                due.append((stream.due_s, key))
                stream.nominal_s += stream.interval_s
                stream.due_s = stream.nominal_s + self.rng.uniform(0.0, SCHEDULER_JITTER_S)
        due.sort()
        return due
