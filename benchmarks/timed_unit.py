"""One unit through every phase on a station file, timed by the wall clock: what the rig benchmarks
(``inav.py``, ``turntable.py``) compare (the sequencer sleeps for real, as on the line)."""

from __future__ import annotations

import time
from pathlib import Path

from magline.core.plugins import load_plugins
from magline.core.record import RunRecord
from magline.core.sequencer import Sequencer
from magline.core.station import load_station


def timed_unit(path: Path, serial: str) -> tuple[RunRecord, float]:
    seq = Sequencer(load_station(path), load_plugins(), path.parent, sleep=time.sleep)
    started = time.monotonic()
    try:
        return seq.run_unit(serial), time.monotonic() - started
    finally:
        seq.close()
