"""A stop signal to ``magline station`` (``systemctl stop``, a PC shutting down) while a unit is being
tumbled (issue 31): the unit is aborted, restored and recorded ABORTED with its phases and raw data,
then the server exits — as ``magline run`` does — never an INCOMPLETE record without readings."""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

from conftest import REPO
from sqlalchemy import create_engine, text
from test_readme_walkthroughs import free_port

MAGLINE = str(Path(sys.executable).with_name("magline"))


def call(url: str, body: dict | None = None) -> dict:
    data = json.dumps(body).encode() if body is not None else None
    request = urllib.request.Request(url, data=data, headers={"Content-Type": "application/json"},
                                     method="POST" if body is not None else "GET")
    with urllib.request.urlopen(request, timeout=10) as answer:
        return json.loads(answer.read())


def started_station(tmp_path) -> tuple[subprocess.Popen, str]:
    """``magline station`` on the demo station, answering: the process and its address."""
    station = tmp_path / "demo.yaml"
    shutil.copy(REPO / "stations" / "demo.yaml", station)
    port = free_port()
    server = subprocess.Popen([MAGLINE, "station", str(station), "--port", str(port)], cwd=tmp_path,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert server.stdout.readline().startswith("station screen on")
        base = f"http://127.0.0.1:{port}"
        deadline = time.monotonic() + 60  # uvicorn starts listening just after the line above
        while True:
            try:
                call(f"{base}/api/state")
                return server, base
            except OSError:
                assert server.poll() is None and time.monotonic() < deadline
                time.sleep(0.1)
    except BaseException:
        server.kill()
        raise


def test_sigterm_aborts_the_unit_under_test_records_it_and_exits(tmp_path):
    server, base = started_station(tmp_path)
    try:
        assert call(f"{base}/api/start", {"serial": "STOP-1"})["started"] == "STOP-1"
        while (call(f"{base}/api/state")["run"] or {}).get("samples", 0) < 100:  # the operator is tumbling
            assert server.poll() is None
            time.sleep(0.1)
        server.send_signal(signal.SIGTERM)
        _, err = server.communicate(timeout=120)
    finally:
        if server.poll() is None:
            server.kill()
    assert server.returncode == 0, err
    assert "ASGI callable returned without completing response" not in err
    # the stop is said once, where a service's log keeps it
    assert err.count("magline station: stopped by SIGTERM: the unit under test is aborted and recorded first") == 1
    engine = create_engine(f"sqlite:///{tmp_path / 'magline-demo-results.sqlite'}")
    with engine.connect() as conn:
        run = conn.execute(text("SELECT id, verdict, cause, aborted_phase FROM runs WHERE serial = 'STOP-1'")).one()
        phases = conn.execute(text(f"SELECT name FROM phases WHERE run_id = {run.id}")).scalars().all()
        readings = conn.execute(text(f"SELECT samples FROM attempts WHERE run_id = {run.id}")).scalars().all()
    engine.dispose()
    assert run.verdict == "aborted" and "stopped: the station was shut down" in run.cause
    assert run.aborted_phase == "acquire" and "acquire" in phases and "record" in phases
    assert readings and readings[0] >= 100  # the readings of the interrupted tumble are kept


def test_sigterm_on_an_idle_station_says_it_stopped_and_exits(tmp_path):
    server, _ = started_station(tmp_path)
    try:
        server.send_signal(signal.SIGTERM)
        _, err = server.communicate(timeout=60)
    finally:
        if server.poll() is None:
            server.kill()
    # an idle server ends as the signal ended it (uvicorn re-raises it: what systemd counts a clean stop)
    assert server.returncode in (0, -signal.SIGTERM), err
    assert "magline station: stopped by SIGTERM: no unit under test" in err
