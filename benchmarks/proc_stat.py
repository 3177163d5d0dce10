"""Every process's ``/proc/PID/stat`` (Linux), for the benchmarks that count the CPU of a station's children or
of a browser's processes: read in one place, since each of them walks the same table."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

TICK = os.sysconf("SC_CLK_TCK")  # the unit of the stat file's CPU times


def process_stats() -> Iterator[tuple[int, int, list[str]]]:
    """(pid, parent pid, the stat fields after the command's name) of each process still there when read;
    field 11 is its user CPU, 12 its system CPU, 13 and 14 those of the children it reaped, in ``TICK``s."""
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        yield int(entry.name), int(fields[1]), fields
