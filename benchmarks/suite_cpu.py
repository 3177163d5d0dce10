"""Where the test suite's CPU goes: the README's test command run under a sampler of every process.

On two cores the suite is bound by CPU (both about 90 % busy over a run), shared among the workers'
in-process simulators and stations, Chromium, and the ``magline run`` / ``magline sim`` subprocesses the
walkthroughs start.  This runs pytest (the README's arguments unless others are given
after ``--``), reads every process's CPU time from ``/proc`` twice a second, and prints the CPU seconds by
kind of process with the suite's wall time.  A process that lives under half a second may be missed.

    python benchmarks/suite_cpu.py [-- PYTEST ARGS]
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from collections import Counter
from pathlib import Path

TICK = os.sysconf("SC_CLK_TCK")


def kind(pid: str) -> str | None:
    """What a process is, from its command line (None when it is gone)."""
    try:
        argv = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
        comm = Path(f"/proc/{pid}/comm").read_text().strip()
    except OSError:
        return None
    line = b" ".join(argv).decode(errors="replace")
    if "chrom" in comm or "chrom" in line.split(" ")[0]:
        for role in ("renderer", "gpu-process", "utility", "zygote"):
            if f"--type={role}" in line:
                return f"chromium ({role})"
        return "chromium (browser)"
    if comm == "node" or "playwright" in line.split(" ")[0]:
        return "playwright driver"
    if "postgres" in comm:
        return "postgresql"
    if "python" in comm or "python" in line.split(" ")[0]:
        if " -c " in f" {line} " and "execnet" not in line and len(argv) > 2 and argv[1] == b"-u":
            return "pytest worker (in-process boards, stations, fits)"
        for command in ("run", "sim", "station", "dashboard", "fit", "check", "spc", "report"):
            if f"magline {command}" in line or f"magline.core.cli {command}" in line:
                return f"magline {command} subprocess"
        if "pytest" in line:
            return "pytest controller"
        if "pip" in line:
            return "pip (the example plugin's venv)"
        return "other python"
    return "other"


def sample(totals: dict[str, list], stop: threading.Event) -> None:
    """Keep each process's latest CPU seconds by pid (those already running at the start from then on)."""
    base: dict[str, float] = {}
    first = True
    while not stop.is_set():
        for pid in os.listdir("/proc"):
            if not pid.isdigit() or pid == str(os.getpid()):
                continue
            try:
                fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            cpu = (int(fields[11]) + int(fields[12])) / TICK
            if first:
                base[pid] = cpu
            if pid not in totals:
                what = kind(pid)
                if what is None:
                    continue
                totals[pid] = [what, 0.0]
            totals[pid][1] = cpu - base.get(pid, 0.0)
        first = False
        stop.wait(0.5)


def main() -> int:
    args = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else ["-q", "-n", "4"]
    totals: dict[str, list] = {}
    stop = threading.Event()
    sampler = threading.Thread(target=sample, args=(totals, stop), daemon=True)
    sampler.start()
    started = time.monotonic()
    code = subprocess.call([sys.executable, "-m", "pytest", *args])
    wall = time.monotonic() - started
    stop.set()
    sampler.join()
    by_kind: Counter[str] = Counter()
    for what, cpu in totals.values():
        by_kind[what] += cpu
    whole = sum(by_kind.values())
    print(f"\nsuite wall time {wall:.0f} s, CPU {whole:.0f} s ({whole / wall / os.cpu_count():.0%} of "
          f"{os.cpu_count()} cores), pytest exit {code}")
    for what, cpu in by_kind.most_common():
        if cpu >= 0.5:
            print(f"  {cpu:7.1f} s  {cpu / whole:5.1%}  {what}")
    return code


if __name__ == "__main__":
    raise SystemExit(main())
