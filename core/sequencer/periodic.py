"""Something done every few seconds on a thread of its own while a block runs: a countdown to the
operator during a long wait, a claim refreshed in the results store while a unit runs."""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager


@contextmanager
def every(period_s: float, action: Callable[[], None], name: str, join_s: float = 2.0) -> Iterator[None]:
    """Call ``action`` every ``period_s`` (first after one period) until the block ends; the thread is
    a daemon and is given ``join_s`` to finish its current call."""
    done = threading.Event()

    def loop() -> None:
        while not done.wait(period_s):
            action()

    thread = threading.Thread(target=loop, name=name, daemon=True)
    thread.start()
    try:
        yield
    finally:
        done.set()
        thread.join(timeout=join_s)
