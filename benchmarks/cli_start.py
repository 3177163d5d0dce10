"""How long a ``magline`` command takes to start (issue 65: ``--help`` and ``check`` within 0.3 s).

Each command is run ``--runs`` times as a user runs it (the installed console script, a new process each
time) and the median and the slowest wall time are printed, beside a bare ``python -c pass`` and the
imports a command that reads a station file and computes needs (NumPy, pydantic, PyYAML, pluggy) for scale:
``--help`` imports none of the first three, ``check`` no NumPy.

Bytecode caches are allowed for the commands whatever the caller's environment says: a user's Python writes
them at the first run, and a shell with ``PYTHONDONTWRITEBYTECODE=1`` (some CI and sandbox images) would
otherwise compile every magline module at every start — 0.13 s of ``magline --help`` on one machine, a cost
no user pays.

    python benchmarks/cli_start.py [--runs 10]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
MAGLINE = str(Path(sys.executable).with_name("magline"))
COMMANDS = {
    "python -c pass": [sys.executable, "-c", "pass"],
    "python: numpy, pydantic, yaml, pluggy": [sys.executable, "-c", "import numpy, pydantic, yaml, pluggy"],
    # what registering every plugin would cost were their options models imported at registration, as they were
    # before they could be named by place: pydantic and the station schema alone, then with every built-in model
    "python: pydantic, the station schema": [sys.executable, "-c", "import magline.core.station.schema"],
    "python: those and every built-in options model": [sys.executable, "-c", "import magline.core.station.schema\n"
                                                       "import magline.plugins.px4.options, "
                                                       "magline.plugins.ardupilot.options, "
                                                       "magline.plugins.inav.options, magline.plugins.mock.options, "
                                                       "magline.plugins.helmholtz.options, "
                                                       "magline.plugins.gimbal.motion, "
                                                       "magline.plugins.turntable.motion, "
                                                       "magline.plugins.power.command, "
                                                       "magline.plugins.power.scpi_supply, "
                                                       "magline.plugins.power.usb_hub, "
                                                       "magline.plugins.current.motor_test, "
                                                       "magline.plugins.current.electronic_load, "
                                                       "magline.core.field.options"],
    "magline --help": [MAGLINE, "--help"],
    "magline check stations/demo.yaml": [MAGLINE, "check", "stations/demo.yaml"],
    "magline check stations/px4-sim.yaml": [MAGLINE, "check", "stations/px4-sim.yaml"],
    "magline sim --help": [MAGLINE, "sim", "--help"],
}


ENV = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}


def wall_s(argv: list[str]) -> float:
    started = time.perf_counter()
    subprocess.run(argv, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True, env=ENV)
    return time.perf_counter() - started


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=10)
    args = parser.parse_args()
    print(f"command start, wall time over {args.runs} runs (median, slowest)")
    for name, argv in COMMANDS.items():
        wall_s(argv)  # the first run fills the file cache and writes the bytecode caches
        times = [wall_s(argv) for _ in range(args.runs)]
        print(f"  {name:<48} {statistics.median(times):6.3f} s  {max(times):6.3f} s", flush=True)


if __name__ == "__main__":
    main()
