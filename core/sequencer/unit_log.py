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
from collections.abc import Iterator
from contextlib import contextmanager

from magline.core.record import RunRecord

LOGGER = logging.getLogger("magline")
LOGGER.addHandler(logging.NullHandler())


class _ToRecord(logging.Handler):
    def __init__(self, record: RunRecord) -> None:
        super().__init__(logging.DEBUG)
        self.record = record

    def emit(self, entry: logging.LogRecord) -> None:
        if self.record.phases:
            try:
                self.record.phases[-1].log.append(f"{entry.name}: {entry.getMessage()}")
            except Exception:  # a logging failure must never stop a unit
                self.handleError(entry)


@contextmanager
def unit_log_capture(record: RunRecord) -> Iterator[None]:
    handler = _ToRecord(record)
    level = LOGGER.level
    LOGGER.addHandler(handler)
    LOGGER.setLevel(logging.INFO)
    try:
        yield
    finally:
        LOGGER.removeHandler(handler)
        LOGGER.setLevel(level)
