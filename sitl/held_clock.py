"""The clock of a scripted motion that stands while the unit is held still.

Why: the SITL peers turn a unit through a scripted tumble, and a current sweep holds the unit still
mid-tumble (the station asks the operator to set it down).  When the hold ends the unit must go on from
the attitude it was held in, not jump to where the script would be had it kept turning.
"""

from __future__ import annotations


class HeldClock:
    """Seconds of motion since ``began``, less every stretch the unit was held."""

    def __init__(self) -> None:
        self.stood_s = 0.0  # the time the unit stood held, all holds ended so far
        self._held_since: float | None = None

    def motion_s(self, began: float, now: float, held: bool) -> float:
        """The motion's time at ``now`` (monotonic seconds) for a motion that began at ``began``; while
        ``held`` it stays at the instant the hold began."""
        if held:
            self._held_since = now if self._held_since is None else self._held_since
            return self._held_since - began - self.stood_s
        if self._held_since is not None:
            self.stood_s, self._held_since = self.stood_s + now - self._held_since, None
        return now - began - self.stood_s
