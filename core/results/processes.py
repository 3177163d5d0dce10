"""Which process wrote a row, and whether it is still there: a ``running`` run or a slot's claim left by
a process that is gone belongs to nobody.  Its own module because the store and the slot claims both
ask it (the claims are written through the store).
"""

from __future__ import annotations

import os
import socket


def owner() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


def alive(writer: str | None) -> bool:
    """Is the process that wrote a ``running`` row still there?  Another PC's process cannot be
    checked and counts as alive; a row without a writer (older versions) as dead."""
    host, _, pid = (writer or "").rpartition(":")
    if not pid.isdigit():
        return False
    if host != socket.gethostname():
        return True
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
