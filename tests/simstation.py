"""Station files pointed at a simulator on a free loopback port, for the backend tests."""

from __future__ import annotations

import json
from pathlib import Path

import yaml
from conftest import REPO, deep_update
from sqlalchemy import create_engine

from magline.core.fit.samples_csv import RawSamples
from magline.core.plugins import load_plugins
from magline.core.record import RunRecord
from magline.core.results.reading import serial_attempts
from magline.core.sequencer import Sequencer
from magline.core.station import load_station

FAST_ACQUISITION = {"samples": 400, "rate_hz": 200.0, "retry_delay_s": 0.0, "timeout_s": 30.0}
# The simulated sensors publish at this rate in the backend tests: slower than the 200 Hz stream, so
# every test sees repeated readings as a real vehicle sends them, yet 400 readings take 4 s, not 40.
FAST_SENSOR_HZ = 100.0


def write_station(example: str, tmp_path: Path, address: str, options: dict | None = None,
                  changes: dict | None = None) -> Path:
    """``stations/<example>`` with the connection moved to ``address`` and a fast acquisition."""
    cfg = yaml.safe_load((REPO / "stations" / example).read_text(encoding="utf-8"))
    part = cfg["default_part"]
    cfg = deep_update(cfg, {"products": {part: {"connection": address, "options": options or {}}},
                            "acquisition": FAST_ACQUISITION,
                            "results": {"path": str(tmp_path / "results.sqlite")}})
    cfg = deep_update(cfg, changes or {})
    path = tmp_path / "station.yaml"
    path.write_text(yaml.safe_dump(cfg, sort_keys=False), encoding="utf-8")
    return path


def run_unit(station: Path, serial: str = "SN-1") -> RunRecord:
    seq = Sequencer(load_station(station), load_plugins(), station.parent, sleep=lambda s: None)
    try:
        return seq.run_unit(serial)
    finally:
        seq.close()


def stored_attempts(results: Path, serial: str) -> list[tuple[int, RawSamples]]:
    """(samples, raw readings) of every stored acquisition attempt of ``serial``, read back through
    the store's own reading API (the blob decoded as ``magline export`` does)."""
    return [(a["samples"], a["raw"]) for a in attempt_rows(results, serial)]


def attempt_rows(results: Path, serial: str) -> list[dict]:
    """Every stored attempt of ``serial`` (the attempts table's columns; ``raw``: its readings)."""
    engine = create_engine(f"sqlite:///{results}")
    try:
        with engine.connect() as conn:
            return serial_attempts(conn, serial)
    finally:
        engine.dispose()


def load_json(path: Path) -> dict:
    return json.loads(path.read_text(encoding="utf-8"))
