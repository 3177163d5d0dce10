"""``magline station``: build the sequencer, the screen state and the runner, serve the app."""

from __future__ import annotations

import errno
import ipaddress
import secrets
import signal
import socket
import sys
import threading
from pathlib import Path
from typing import TYPE_CHECKING, Any

from magline.core.faults import StationFault
from magline.core.operator_ui.screen.app import create_app
from magline.core.operator_ui.screen.runner import UnitRunner
from magline.core.operator_ui.screen.state import ScreenState
from magline.core.plugins import Plugins

if TYPE_CHECKING:
    from magline.core.station import Station


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def build(station: Station, where: Path, plugins: Plugins, token: str | None = None) -> tuple[Any, UnitRunner]:
    """The app and its runner (tests start it on a free port themselves)."""
    from magline.core.sequencer import Sequencer

    state = ScreenState(station)
    plugins.pm.register(state)
    runner = UnitRunner(Sequencer(station, plugins, where), state)
    reports = where / station.main_results.reports if station.main_results.reports is not None else None
    return create_app(state, runner, token, reports), runner


def listening_socket(host: str, port: int) -> socket.socket:
    """The screen's socket, bound before anything is announced: a port another program holds is said
    as the refusal it is, not after a "station screen on …" line that was never true."""
    family, kind, proto, _, address = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0]
    sock = socket.socket(family, kind, proto)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind(address)
        sock.listen(128)  # a browser opened at the announced address waits for the server, never refused
    except OSError:
        sock.close()
        raise
    return sock


def serve(station: Station, where: Path, plugins: Plugins, host: str, port: int) -> int:
    import uvicorn

    try:
        sock = listening_socket(host, port)
    except OSError as exc:
        held = (" — another station screen or program holds it; stop it or give another --port"
                if exc.errno == errno.EADDRINUSE else "")
        print(f"magline station: cannot listen on {host}:{port}: {exc.strerror or exc}{held}", file=sys.stderr)
        return 2
    port = sock.getsockname()[1]  # the port it is on (--port 0: the one the system chose)
    token = None if is_loopback(host) else secrets.token_urlsafe(18)
    try:
        app, runner = build(station, where, plugins, token)
    except (StationFault, OSError, ValueError) as exc:
        sock.close()
        print(str(exc), file=sys.stderr)
        return 2
    address = f"http://{host}:{port}/"
    if token:
        print(f"operator token (shown once): {token}\nopen {address}?token={token}", flush=True)
    else:
        print(f"station screen on {address}", flush=True)
    server = _station_server(uvicorn, uvicorn.Config(app, host=host, port=port, log_level="warning"), runner)
    try:
        server.run(sockets=[sock])
    finally:
        runner.close()
        sock.close()
    return 0


STOP_WAIT_S = 60.0  # a unit aborted by a stop signal gets this long to be restored and recorded


def _station_server(uvicorn: Any, config: Any, runner: UnitRunner) -> Any:
    """uvicorn's server, with a stop signal (``systemctl stop``, a PC shutting down, Ctrl-C) first
    aborting every unit under test — restored where the backend can, recorded ABORTED with its raw
    data, exactly as ``magline run`` does — and only then shutting the server down.  uvicorn alone
    would stop serving and re-raise the signal, killing the process with the unit mid-run: a record
    left INCOMPLETE without phases or readings.  A second signal stops at once."""

    class StationServer(uvicorn.Server):
        stopping = said = False

        def handle_exit(self, sig: int, frame: Any) -> None:
            if not self.said:  # said once, where the service's log keeps it
                self.said, busy = True, runner.busy()
                print(f"magline station: stopped by {signal.Signals(sig).name}: "
                      + ("the unit under test is aborted and recorded first" if busy else "no unit under test"),
                      file=sys.stderr, flush=True)
            if self.stopping or not runner.busy():
                super().handle_exit(sig, frame)
                return
            self.stopping = True
            runner.abort("stopped: the station was shut down")
            threading.Thread(target=self._exit_when_recorded, name="magline-stop", daemon=True).start()

        def _exit_when_recorded(self) -> None:
            runner.wait(STOP_WAIT_S)
            self.should_exit = True

    return StationServer(config)
