"""Waiting for a vehicle without taking this process's own stalls for the vehicle's silence.

Why: a wait for the next message is judged by the clock, and the clock goes on while the station
process itself does not run — a long garbage collection, a paused VM, a starved CI worker.  Such a
wait comes back past its deadline without having listened; judged then, a good unit's link is
declared lost (or its compass silent) though its messages wait in the socket.  A CI run ERRORed a
good unit so ("nothing received for 3 s").  So waits are cut into short slices, and a slice that took
:data:`STALL_S` longer than asked was such a stall: its excess is added back to the deadline, and the
backends subtract it from the silence they judge.
"""

from __future__ import annotations

import queue
import time
from typing import Any

STALL_S = 0.25  # a wait this much longer than asked was a stall of this process, not listening
SLICE_S = 0.2  # waits are cut this short: a stall shows as a slice that overran, whatever its length


def stall_s(asked: float, wait: float) -> float:
    """How long this process stalled in a wait of ``wait`` seconds begun at ``asked`` (monotonic): the
    overrun when it exceeds :data:`STALL_S`, else 0."""
    overrun = time.monotonic() - asked - wait
    return overrun if overrun > STALL_S else 0.0


def get_listening(inbox: queue.Queue, timeout_s: float) -> Any:
    """``inbox.get`` within ``timeout_s`` of listening; :class:`queue.Empty` when nothing came."""
    deadline = time.monotonic() + timeout_s
    while True:
        asked = time.monotonic()
        wait = min(SLICE_S, max(deadline - asked, 0.0))
        try:
            return inbox.get(timeout=wait)
        except queue.Empty:
            stalled = stall_s(asked, wait)
            if stalled:
                deadline += stalled
            elif time.monotonic() >= deadline:
                raise
