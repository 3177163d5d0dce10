"""Let a unit warm up before its tumble: ``acquisition.warm_up_s`` of the unit's own uptime.

Why: a magnetometer's offset settles while the board warms after power-on.  The fit's drift test
and the settle check see a warm-up only where it moves the offset by more than about 14 offset σ
within a tumble (docs/quality.md, "What the drift test cannot see"); a smaller or later one passes them
unseen, bends the calibration and may fail the post-reboot field check of a good unit.  No test
on the readings can bound a drift below its own σ, so a line whose units warm up during
calibration bounds it by time: the tumble starts only once the unit has run ``warm_up_s``.

The unit's own clock decides, not a fixed sleep: a unit powered on a minute before its serial was
scanned starts at once, one plugged in a second ago waits the rest.  A MAVLink reboot restarts the
uptime but keeps the board warm, so the uptime never overstates how warm it is.  A backend that
cannot say its uptime (no ``uptime_s``, or the autopilot does not answer for it) gets the whole
``warm_up_s`` counted from the moment asked: the safe side.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

# how often the wait looks at the operator's abort and re-reads the unit's clock
STEP_S = 0.25


@dataclass(frozen=True)
class WarmUp:
    """What the wait found: the unit's uptime when asked (None: it did not say), and the seconds waited."""

    uptime_s: float | None
    waited_s: float

    def words(self, need_s: float) -> str:
        ran = "its uptime unknown" if self.uptime_s is None else f"up {self.uptime_s:.1f} s"
        if self.waited_s <= 0:
            return f"warm: {ran}, acquisition.warm_up_s {need_s:g} s"
        return f"warmed up: {ran}, waited {self.waited_s:.1f} s for acquisition.warm_up_s {need_s:g} s"


def wait_until_warm(need_s: float, uptime_s: Callable[[], float | None], on_wait: Callable[[float], None],
                    check_abort: Callable[[], None], sleep: Callable[[float], None] = time.sleep,
                    clock: Callable[[], float] = time.monotonic) -> WarmUp:
    """Return once the unit has run ``need_s`` by ``uptime_s()``, or ``need_s`` from now when it does
    not say.  The uptime is asked again when the wait is due and the rest waited once more where the
    unit's clock is behind (it rebooted meanwhile): the unit's clock is waited for, never assumed.

    ``on_wait(left_s)`` is called once before a wait (the operator's prompt); ``check_abort()`` every
    :data:`STEP_S` (it raises when the operator stops the unit)."""
    first = uptime_s()
    if first is not None and first >= need_s:
        return WarmUp(first, 0.0)
    on_wait(need_s - (first or 0.0))
    started = clock()
    due = started + need_s - (first or 0.0)
    asked_again = first is None  # nothing to ask again when it never said
    while True:
        now = clock()
        if now >= due:
            if asked_again:
                return WarmUp(first, now - started)
            asked_again = True
            up = uptime_s()
            if up is None or up >= need_s:
                return WarmUp(first, now - started)
            due = now + need_s - up
        check_abort()
        sleep(min(due - now, STEP_S))
