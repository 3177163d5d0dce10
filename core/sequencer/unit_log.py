"""Library chatter goes to the unit's record, not the operator's console.

Why: client libraries log what an operator cannot act on (MAVSDK's "Sending again, retries to do",
pymavlink's reconnect notes).  Plugins log through the ``magline`` logger tree (the PX4 backend
routes MAVSDK's own log there); while a unit runs, every such line is appended to the log of the
phase that is running (or last ran), where a quality engineer finds it next to the outcome.
Outside a unit the ``magline`` logger has a NullHandler, so Python's last-resort handler never
prints library warnings on the console.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from magline.core.record import RunRecord


LOGGER = logging.getLogger("magline")
LOGGER.addHandler(logging.NullHandler())


class _ToRecord(logging.Handler):
    def __init__(self, record: RunRecord, thread: int | None) -> None:
        super().__init__(logging.DEBUG)
        self.record = record
        self.thread = thread

    def emit(self, entry: logging.LogRecord) -> None:
        if self.thread is not None and entry.thread != self.thread:
            return  # another slot's unit (slots run side by side, one thread each)
        if self.record.phases:
            try:
                self.record.phases[-1].log.append(f"{entry.name}: {entry.getMessage()}")
            except Exception:  # a logging failure must never stop a unit
                self.handleError(entry)


@contextmanager
def unit_log_capture(record: RunRecord, this_thread_only: bool = False) -> Iterator[None]:
    """While the block runs, ``magline`` log lines go to the record (``this_thread_only``: only
    those of the calling thread, when several units run side by side)."""
    handler = _ToRecord(record, threading.get_ident() if this_thread_only else None)
    LOGGER.addHandler(handler)
    with _LEVEL_LOCK:
        global _CAPTURING
        _CAPTURING += 1
        LOGGER.setLevel(logging.INFO)
    try:
        yield
    finally:
        LOGGER.removeHandler(handler)
        with _LEVEL_LOCK:
            _CAPTURING -= 1
            if not _CAPTURING:
                LOGGER.setLevel(logging.NOTSET)


_LEVEL_LOCK = threading.Lock()
_CAPTURING = 0  # units capturing now (the level goes back when the last one ends)
