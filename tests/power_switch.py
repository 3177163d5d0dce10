"""A stand-in for a fixture's power switch, for the ``command`` power control tests:
``on`` starts a simulator process (detached) and returns once it listens; ``off`` kills it
without warning, which is what cutting power does to a flight controller.

    python power_switch.py on PIDFILE -- SIM ARGS...
    python power_switch.py off PIDFILE
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path


def main(argv: list[str]) -> int:
    action, pidfile = argv[0], Path(argv[1])
    if action == "off":
        pid = int(pidfile.read_text())
        os.kill(pid, signal.SIGKILL)
        pidfile.unlink()
        return 0
    sim_args = argv[argv.index("--") + 1:]
    log = pidfile.with_suffix(".log")
    with log.open("w") as out:
        proc = subprocess.Popen([sys.executable, "-m", "magline.core.cli", "sim", *sim_args], stdout=out,
                                stderr=subprocess.STDOUT, start_new_session=True)
    deadline = time.monotonic() + 20
    while "listening on" not in log.read_text():
        if proc.poll() is not None or time.monotonic() > deadline:
            print(f"simulator did not start: {log.read_text()[-300:]}", file=sys.stderr)
            return 1
        time.sleep(0.05)
    pidfile.write_text(str(proc.pid))
    return 0

if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
