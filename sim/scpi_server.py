"""The network half of every simulated SCPI instrument: a TCP server speaking newline-terminated
commands (``;`` separates several on one line), one thread per client, an error queue.

Subclasses implement :meth:`ScpiServer.command` for their instrument; ``*IDN?``, ``*CLS`` and
``SYST:ERR?`` and the "Undefined header" error for anything unknown are handled here, as real
instruments do.
"""

from __future__ import annotations

import contextlib
import socket
import threading
from collections import deque

from magline.core.links.mavlink_tap import received
from magline.sim.transport import parse_listen

NO_ERROR = '0,"No error"'


class ScpiServer:
    identity = "magline,SIM,0001,1.0"

    def __init__(self, listen: str) -> None:
        scheme, host, port = parse_listen(listen)
        if scheme != "tcp":
            raise ValueError(f"{type(self).__name__} listens on tcp:HOST:PORT")
        self.errors: deque[str] = deque(maxlen=20)
        self.log: list[str] = []  # every command received, for tests
        self.lock = threading.RLock()
        self.listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.listener.bind((host, port))
        self.listener.listen(4)
        self.address = f"tcp:{host}:{self.listener.getsockname()[1]}"
        self.silent = False  # a test switches this on: the instrument stops answering
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    @property
    def visa_resource(self) -> str:
        _, host, port = self.address.split(":")
        return f"TCPIP0::{host}::{port}::SOCKET"

    def start(self) -> ScpiServer:
        self._thread = threading.Thread(target=self._serve, name=type(self).__name__, daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        with contextlib.suppress(OSError):
            self.listener.close()
        if self._thread is not None:
            self._thread.join(timeout=5)

    def wait_stopped(self) -> None:
        """Block until :meth:`stop` (what ``magline sim`` waits on while it serves)."""
        while not self._stop.wait(0.5):
            pass

    def __enter__(self):
        return self if self._thread is not None else self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _serve(self) -> None:
        self.listener.settimeout(0.2)
        while not self._stop.is_set():
            try:
                client, _ = self.listener.accept()
            except (TimeoutError, OSError):
                continue
            threading.Thread(target=self._session, args=(client,), daemon=True).start()

    def _session(self, client: socket.socket) -> None:
        buffer = b""
        with client:
            for data in received(client, self._stop):
                buffer += data
                while b"\n" in buffer:
                    line, _, buffer = buffer.partition(b"\n")
                    for command in line.decode(errors="replace").split(";"):
                        reply = self.handle(command.strip())
                        if reply is not None and not self.silent:
                            client.sendall(reply.encode() + b"\n")

    def handle(self, command: str) -> str | None:
        if not command:
            return None
        with self.lock:
            self.log.append(command)
            head, _, arg = command.partition(" ")
            head = head.upper()
            if head == "*IDN?":
                return self.identity
            if head == "*CLS":
                self.errors.clear()
                return None
            if head in ("SYST:ERR?", "SYSTEM:ERROR?", "SYST:ERR:NEXT?"):
                return self.errors.popleft() if self.errors else NO_ERROR
            try:
                return self.command(head, arg.strip())
            except KeyError:
                self.errors.append(f'-113,"Undefined header; {command[:30]}"')
            except ValueError:
                self.errors.append('-104,"Data type error"')
            return None

    def command(self, head: str, arg: str) -> str | None:
        """One instrument command (upper-case header, argument); raise KeyError when unknown."""
        raise KeyError(head)
