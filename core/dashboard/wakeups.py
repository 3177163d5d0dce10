"""What wakes the dashboard's live pages: on PostgreSQL the store's writers' ``NOTIFY`` (every station's
record, at commit), on SQLite the pages' own poll of the file.

Why both: a notification reaches a page at once and spares the server a query every half second per
page; a poll still runs, slower, so a lost listener connection never leaves a page stale.
"""

from __future__ import annotations

import threading
from typing import TYPE_CHECKING

from magline.core.results.store import RUNS_CHANNEL

if TYPE_CHECKING:
    from magline.core.dashboard.store import ReadOnlyStore

POLL_S = 0.5  # without notifications
POLL_NOTIFIED_S = 5.0  # beside them
RECONNECT_S = 2.0


class Wakeups:
    """A counter that goes up at every notification: a page's stream reads the store again when it moved,
    or when ``poll_s`` has passed."""

    def __init__(self, store: ReadOnlyStore) -> None:
        self.url = store.url if store.kind == "postgresql" else None
        self.poll_s = POLL_NOTIFIED_S if self.url else POLL_S
        self.count = 0
        self._lock = threading.Lock()  # the pages read ``count`` without it: an int read is atomic
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        if self.url:
            self._thread = threading.Thread(target=self._listen, name="dashboard-listen", daemon=True)
            self._thread.start()

    def _bump(self) -> None:
        with self._lock:
            self.count += 1

    def _listen(self) -> None:
        import psycopg

        while not self._stop.is_set():
            try:
                with psycopg.connect(self.url, autocommit=True) as conn:
                    conn.execute(f"LISTEN {RUNS_CHANNEL}")
                    self._bump()  # (re)connected: whatever happened meanwhile is read once
                    while not self._stop.is_set():
                        for _ in conn.notifies(timeout=1.0):
                            self._bump()
            except psycopg.Error:
                self._stop.wait(RECONNECT_S)  # the poll carries on meanwhile

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5)
