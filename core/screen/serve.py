"""``magline station``: build the sequencer, the screen state and the runner, serve the app."""

from __future__ import annotations

import ipaddress
import secrets
import sys
from pathlib import Path
from typing import Any

from magline.core.faults import StationFault
from magline.core.plugins import Plugins
from magline.core.screen.app import create_app
from magline.core.screen.runner import UnitRunner
from magline.core.screen.state import ScreenState
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


def serve(station: Station, where: Path, plugins: Plugins, host: str, port: int) -> int:
    import uvicorn

    token = None if is_loopback(host) else secrets.token_urlsafe(18)
    try:
        app, runner = build(station, where, plugins, token)
    except (StationFault, OSError, ValueError) as exc:
        print(str(exc), file=sys.stderr)
        return 2
    address = f"http://{host}:{port}/"
    if token:
        print(f"operator token (shown once): {token}\nopen {address}?token={token}", flush=True)
    else:
        print(f"station screen on {address}", flush=True)
    try:
        uvicorn.run(app, host=host, port=port, log_level="warning")
    finally:
        runner.close()
    return 0
