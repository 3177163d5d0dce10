"""Stopping a unit cleanly: Ctrl-C, SIGTERM or an Abort button become :class:`UnitAborted`.

Why a switch rather than letting ``KeyboardInterrupt`` fly: an interrupt that lands while the
DUT is being restored, or half-way through writing its calibration, would leave the unit changed
and the record unwritten.  Inside :meth:`AbortSwitch.shielded` (restore, persist, record) a request
is only noted and honoured at the next safe point; elsewhere a signal raises at once, so a long
wait (acquisition, reboot) stops immediately.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from magline.core.faults import UnitAborted

SIGNAL_NAMES = {signal.SIGINT: "Ctrl-C", signal.SIGTERM: "SIGTERM"}


class AbortSwitch:
    def __init__(self) -> None:
        self.requested: str | None = None
        self._shield = 0

    def request(self, reason: str) -> None:
        """Ask the current unit to stop.  On the main thread outside a shield it raises at once;
        from another thread (a web screen's Abort) it is honoured at the next :meth:`check`."""
        self.requested = reason
        if not self._shield and threading.current_thread() is threading.main_thread():
            raise UnitAborted(reason)

    def note(self, reason: str) -> None:
        """Ask the unit running on another thread to stop, whatever thread asks (a server's signal
        handler runs on the main thread but must not raise there): honoured at the unit's next check."""
        self.requested = reason

    def check(self) -> None:
        """A safe point: raise :class:`UnitAborted` when a stop was requested."""
        if self.requested is not None and not self._shield:
            raise UnitAborted(self.requested)

    @contextmanager
    def shielded(self) -> Iterator[None]:
        """Requests made meanwhile wait for the next :meth:`check` (used around restore and writes)."""
        self._shield += 1
        try:
            yield
        finally:
            self._shield -= 1

    def clear(self) -> None:
        self.requested = None

    @contextmanager
    def signals(self) -> Iterator[None]:
        """Turn SIGINT and SIGTERM into abort requests while the block runs (main thread only)."""
        def handler(signum: int, frame: object) -> None:
            self.request(f"stopped by {SIGNAL_NAMES.get(signum, f'signal {signum}')}")

        previous: dict[int, Callable | int | None] = {}
        for sig in SIGNAL_NAMES:
            previous[sig] = signal.signal(sig, handler)
        try:
            yield
        finally:
            for sig, old in previous.items():
                signal.signal(sig, old)
