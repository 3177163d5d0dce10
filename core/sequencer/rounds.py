"""Shared acquisition rounds: one motion, several slots, each slot reading its own unit.

Why a coordinator: the gimbal (or the operator's tumble of a cradle) moves every unit at once, so a
pattern is worth running only when every slot that still needs samples is ready for it.  A round
starts when no slot is still connecting or deciding (fitting the last attempt) and at least one
asks for samples; it stops when the last of its slots has its samples or left.  A slot that needs
another attempt asks again and gets the next round, with whoever else needs one; slots with an
accepted attempt are no longer in the line-up.  A slot that fails, errs or is aborted leaves, and
never holds the others up.

On a one-unit station the same object runs the motion around each attempt with one slot.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from enum import Enum

from magline.core.motion import Motion

POLL_S = 0.1  # how often a waiting slot checks for its abort


def wait_or_abort(cond: threading.Condition, check_abort: Callable[[], None]) -> None:
    """Wait on ``cond`` (held by the caller) for at most ``POLL_S``, then check for an abort with
    the condition released, so an aborting slot never blocks the others' line-up."""
    cond.wait(POLL_S)
    cond.release()
    try:
        check_abort()
    finally:
        cond.acquire()


class SlotState(Enum):
    BEFORE = "before"  # identifying, connecting: will ask for samples
    WAITING = "waiting"  # asked for the next round
    READING = "reading"  # in the current round
    DECIDING = "deciding"  # read its samples, fitting them (may ask again)
    GONE = "gone"  # no more samples needed (accepted, failed, errored, aborted)


class MotionRounds:
    def __init__(self, motion: Motion, slots: list[str],
                 started: Callable[[int, list[str]], None] = lambda r, s: None,
                 stopped: Callable[[int, list[str]], None] = lambda r, s: None) -> None:
        self.motion = motion
        self.state = dict.fromkeys(slots, SlotState.BEFORE)
        self.round = 0
        self._members: list[str] = []  # the slots of the running round
        self._moving = False
        self._failure: BaseException | None = None  # the motion would not start: said to the round's slots
        self._guide: tuple[int, object] | None = None  # (round, what guides its operator), made by the first slot
        self._started, self._stopped = started, stopped
        self._cond = threading.Condition()

    @contextmanager
    def shared_round(self, slot: str, check_abort: Callable[[], None]) -> Iterator[int]:
        """Wait for the next round that includes ``slot``, yield its number while the fixture moves;
        on leaving the block the slot is done reading (the motion stops after the last one)."""
        with self._cond:
            self.state[slot] = SlotState.WAITING
            self._cond.notify_all()
            try:
                while self.state[slot] is SlotState.WAITING:
                    if self._ready():
                        self._begin()
                    else:
                        wait_or_abort(self._cond, check_abort)
            except BaseException:
                self.state[slot] = SlotState.GONE
                self._cond.notify_all()
                raise
            if self._failure is not None and slot in self._members:
                failure = self._failure
                self._finish(slot)
                raise failure
            number = self.round
        try:
            yield number
        finally:
            with self._cond:
                self._finish(slot)

    @property
    def members(self) -> list[str]:
        """The slots of the current (or last) round: what a plugin sharing more than the motion
        (a coil's schedule) lines up."""
        with self._cond:
            return list(self._members)

    def guide(self, number: int, make: Callable[[list[str]], object]) -> object:
        """What guides the operator through round ``number`` (a turntable's tilts): made once, by the first
        slot that asks, from the round's members; every slot of the round shares it."""
        with self._cond:
            if self._guide is None or self._guide[0] != number:
                self._guide = (number, make(list(self._members)))
            return self._guide[1]

    def leave(self, slot: str) -> None:
        """The slot needs no more samples (accepted, or its unit ended): never wait for it again."""
        with self._cond:
            if self.state.get(slot) is not SlotState.GONE:
                self.state[slot] = SlotState.GONE
                self._cond.notify_all()

    # ------------------------------------------------------------------ under the lock
    def _ready(self) -> bool:
        states = set(self.state.values())
        return not self._moving and SlotState.BEFORE not in states and SlotState.DECIDING not in states \
            and SlotState.READING not in states

    def _begin(self) -> None:
        self.round += 1
        self._members = [s for s, st in self.state.items() if st is SlotState.WAITING]
        for s in self._members:
            self.state[s] = SlotState.READING
        self._failure = None
        try:
            self.motion.start(self.round, list(self._members))
            self._moving = True
            self._started(self.round, list(self._members))
        except Exception as exc:  # every slot of the round is told why; none is judged
            self._failure = exc
            self._moving = True  # stopped (harmlessly) when the last member leaves
        self._cond.notify_all()

    def _finish(self, slot: str) -> None:
        if self.state.get(slot) is SlotState.READING:
            self.state[slot] = SlotState.DECIDING
        if self._moving and not any(self.state[s] is SlotState.READING for s in self._members):
            self._moving = False
            try:
                self.motion.stop()
            finally:
                if self._failure is None:
                    self._stopped(self.round, list(self._members))
        self._cond.notify_all()
