"""One coil schedule for every unit in the coil: each step applied once, when every unit still in
the round is ready for it.

Why a dynamic line-up rather than a barrier: a unit whose link is lost mid-schedule leaves, and
the others go on without it (a broken barrier would stop them all).  The coil is switched off only
when the last unit has left.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import TYPE_CHECKING

from numpy.typing import NDArray

from magline.plugin import wait_or_abort

if TYPE_CHECKING:
    from magline.plugins.helmholtz.coil import CoilDriver


class SharedSchedule:
    def __init__(self, coil: CoilDriver, steps: NDArray, members: list[str], coil_lock: threading.RLock) -> None:
        self.coil = coil
        self.coil_lock = coil_lock
        self.steps = steps
        self.members = set(members)
        self.ready: dict[str, int] = {}
        self.applied = -1
        self._cond = threading.Condition()

    @property
    def done(self) -> bool:
        return not self.members

    def step(self, slot: str, index: int, check_abort: Callable[[], None]) -> None:
        """Return once the coil holds step ``index`` (the last unit to be ready applies it)."""
        with self._cond:
            self.ready[slot] = index
            while self.applied < index:
                if all(self.ready.get(m, -1) >= index for m in self.members):
                    with self.coil_lock:
                        self.coil.apply(self.steps[index])
                    self.applied = index
                    self._cond.notify_all()
                    break
                wait_or_abort(self._cond, check_abort)

    def leave(self, slot: str) -> None:
        """The unit has its samples, or stopped: the next steps do not wait for it; the last one out
        switches the coil's field to zero."""
        with self._cond:
            self.members.discard(slot)
            self._cond.notify_all()
            if not self.members:
                with self.coil_lock:
                    self.coil.apply(self.steps[-1] * 0.0)
