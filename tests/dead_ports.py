"""Loopback addresses where no vehicle answers, each the way a real line meets it."""

from __future__ import annotations

import contextlib
import socket
from collections.abc import Iterator


@contextlib.contextmanager
def refused_port() -> Iterator[int]:
    """Nothing listens: a TCP connect is refused at once."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    yield port


@contextlib.contextmanager
def never_accepting_port() -> Iterator[int]:
    """A listener whose accept queue is full: the kernel drops further SYNs and a blocking
    connect() hangs (about two minutes) — a board whose TCP server is wedged."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(0)
    port = server.getsockname()[1]
    fillers = []
    for _ in range(3):
        c = socket.socket()
        c.setblocking(False)
        with contextlib.suppress(BlockingIOError):
            c.connect(("127.0.0.1", port))
        fillers.append(c)
    try:
        yield port
    finally:
        for c in fillers:
            c.close()
        server.close()


@contextlib.contextmanager
def silent_port(kind: str = "tcp") -> Iterator[int]:
    """Connections are taken (TCP) or datagrams received (UDP), and nothing is ever sent back."""
    server = socket.socket(type=socket.SOCK_STREAM if kind == "tcp" else socket.SOCK_DGRAM)
    server.bind(("127.0.0.1", 0))
    if kind == "tcp":
        server.listen(16)
    try:
        yield server.getsockname()[1]
    finally:
        server.close()
