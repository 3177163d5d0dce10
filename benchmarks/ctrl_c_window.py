"""Where a Ctrl-C during a command's start still ends in Python's own error (issue 65; figures printed, never
asserted).

``magline`` holds its handler from its first line of code (``core/entry.py``): an interrupt after it ends with
one line and exit 2.  Before it, CPython is still starting — its ``site`` runs the ``.pth`` files of the
environment (the editable install's import hook, setuptools' ``distutils-precedence.pth``) — and an interrupt
there is CPython's "Fatal Python error: init_import_site".  This sends SIGINT to ``magline check`` after 0, 1, …
``--max-ms`` milliseconds from the spawn, ``--rounds`` times each, and prints at which delays a traceback or a
fatal error was seen.  Run it with each installed ``magline`` to compare installs:

    python benchmarks/ctrl_c_window.py [--magline PATH] [--rounds 5] [--max-ms 40]
"""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--magline", default=str(Path(sys.executable).with_name("magline")))
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--max-ms", type=int, default=40)
    args = parser.parse_args()
    bad: dict[int, int] = {}
    one_line = 0
    for _ in range(args.rounds):
        for delay_ms in range(args.max_ms):
            proc = subprocess.Popen([args.magline, "check", str(REPO / "stations" / "demo.yaml")],
                                    stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            time.sleep(delay_ms / 1000)
            proc.send_signal(signal.SIGINT)
            _, err = proc.communicate(timeout=60)
            if "Traceback" in err or "Fatal Python error" in err or "Exception ignored" in err:
                bad[delay_ms] = bad.get(delay_ms, 0) + 1
            elif "interrupted (Ctrl-C)" in err:
                one_line += 1
    runs = args.rounds * args.max_ms
    print(f"{args.magline}: {runs} interrupts at 0–{args.max_ms - 1} ms after the spawn")
    print(f"  Python's own error or a traceback at (ms: count): {dict(sorted(bad.items())) or 'none'}")
    print(f"  magline's one line and exit 2: {one_line}; the rest ended before or without a word")


if __name__ == "__main__":
    main()
