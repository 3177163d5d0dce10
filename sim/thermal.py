"""How warm the simulated board is: the state behind the ``mag_warmup`` fault.

Why a state of its own: a board's compass offsets move with its temperature, and a temperature does
not start again when the firmware does.  A MAVLink reboot keeps the board powered (it goes on
warming); only a power cut lets it cool, at the same time constant (one lumped thermal mass).  A
warm-up that restarted at every boot made the post-reboot field check see a cold sensor seconds
after a reboot that had not cooled anything.
"""

from __future__ import annotations

import math


class BoardWarmth:
    """The board's warmth in [0, 1]: 0 at room temperature, 1 settled at its operating temperature.

    First order with time constant ``tau_s``: it rises towards 1 while powered and falls towards 0
    while not.  The board starts cold and unpowered."""

    def __init__(self, tau_s: float, now: float) -> None:
        if tau_s <= 0.0:
            raise ValueError(f"the warm-up time constant must be positive, not {tau_s}")
        self.tau_s = tau_s
        self._since = now
        self._warmth_then = 0.0
        self._powered = False

    def at(self, now: float) -> float:
        """The warmth ``now``."""
        decay = math.exp(-max(now - self._since, 0.0) / self.tau_s)
        if self._powered:
            return 1.0 - (1.0 - self._warmth_then) * decay
        return self._warmth_then * decay

    def powered(self, on: bool, now: float) -> None:
        """The supply went on (``on``) or off ``now``; the same state again changes nothing."""
        if on == self._powered:
            return
        self._warmth_then = self.at(now)
        self._since = now
        self._powered = on
