"""A clock that moves only when a test steps it: stands in for a module's ``time`` (``monotonic``, ``sleep``) or
for a ``clock=`` callable, so how late a thread comes back is the test's to say, not the machine's."""

from __future__ import annotations


class SteppedClock:
    def __init__(self, now: float = 1024.0) -> None:
        self.now = now  # 1024: a binary number, so steps of binary fractions add up exactly

    def monotonic(self) -> float:
        return self.now

    def __call__(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.now += max(seconds, 0.0)
