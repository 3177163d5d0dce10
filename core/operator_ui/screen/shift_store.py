"""The shift's units and the recent ones, as the results store holds them, for the station screen.

Why the store and not the screen's own memory: a screen restarted mid-shift, or a second screen of the
same station, counted only what it had run itself ("0 units this shift" beside a store holding forty).
Read after each unit and every few seconds; a store that cannot be read leaves what the screen counted.
"""

from __future__ import annotations

import threading
from datetime import UTC, datetime
from typing import TYPE_CHECKING, Any

from magline.core.quality.trends import Shifts
from magline.core.results.contract import HoldsRecordsInSql
from magline.core.results.instants import stored_form

if TYPE_CHECKING:
    from collections.abc import Callable

    from magline.core.operator_ui.screen.state import ScreenState

POLL_S = 3.0  # how soon a unit another screen of the station recorded shows here


class ShiftFromStore:
    """Reads the station's units of the running shift (``station.shifts``; the day when unset) from its
    results store's engine and hands them to the screen's state, after each unit and every ``POLL_S``."""

    def __init__(self, station: Any, sink: Any, state: ScreenState,
                 now: Callable[[], datetime] = lambda: datetime.now(UTC)) -> None:
        self.station_id = station.station.id
        self.shifts = Shifts.parse(station.station.shifts)
        self.engine = _records_engine(sink)
        self.state, self.now = state, now
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def read(self) -> dict[str, Any] | None:
        if self.engine is None:
            return None
        from sqlalchemy.exc import SQLAlchemyError

        from magline.core.operator_ui.screen.state import RECENT
        from magline.core.results.reading import shift_units

        since = stored_form(self.shifts.start_of(self.now()))
        try:
            with self.engine.connect() as conn:
                return shift_units(conn, self.station_id, since, RECENT)
        except SQLAlchemyError:
            return None  # the store's own faults are said by the store line and the record phase

    def refresh(self) -> None:
        summary = self.read()
        if summary is not None:
            self.state.units_from_store(summary)

    def follow(self) -> None:
        """Refresh now and every ``POLL_S`` on a thread until :meth:`close`."""
        self.refresh()

        def loop() -> None:
            while not self._stop.wait(POLL_S):
                self.refresh()

        self._thread = threading.Thread(target=loop, name="shift-from-store", daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5)


def _records_engine(sink: Any) -> Any:
    """Where this station's records are written first (a forwarding store's outbox, which keeps them after
    forwarding: the screen does not wait on a server); None for a sink without one (a plugin's): then the
    screen counts what it ran itself."""
    return sink.record_engine if isinstance(sink, HoldsRecordsInSql) else None
