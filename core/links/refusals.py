"""How long every connection to an address has been refused.

Why: a station started against an address where nothing listens (the simulator not started, a wrong
port) waited its whole connect timeout, 10 s and more, to say so.  A board that boots accepts within a
moment of listening; a refusal that lasts ``NOTHING_LISTENS_S`` on the first connection is told at once.
After a power cycle the backends keep retrying to their boot timeout (a firmware's SITL restarts its
process and refuses meanwhile).
"""

from __future__ import annotations

import time

NOTHING_LISTENS_S = 3.0  # refused this long on a first connection: nothing listens there


def refused(exc: BaseException | None) -> bool:
    """Whether ``exc``, or what it was raised from, is a refused connection."""
    while exc is not None:
        if isinstance(exc, ConnectionRefusedError):
            return True
        exc = exc.__cause__ or exc.__context__
    return False


class Refusals:
    """Counts the time since the first of an unbroken run of refused connections."""

    def __init__(self, give_up_s: float | None) -> None:
        self.give_up_s = give_up_s
        self.since: float | None = None

    def over(self, exc: BaseException | None) -> bool:
        """Note one failed attempt; True when connections have been refused for ``give_up_s`` (never
        when ``give_up_s`` is None)."""
        if not refused(exc):
            self.since = None
            return False
        now = time.monotonic()
        self.since = now if self.since is None else self.since
        return self.give_up_s is not None and now - self.since >= self.give_up_s

    def words(self, address: str) -> str:
        return (f"nothing listens on {address}: every connection was refused for {self.give_up_s:g} s — is the "
                "board (or its simulator) running there, and is that the product's connection?")
