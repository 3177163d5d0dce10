"""PX4's SITL process, powered on and cut as a bench supply would, for the station's ``command`` power.

A posix PX4 cannot reset itself (a reboot request there panics: ``platforms/common/shutdown.cpp`` has no
board reset), so the station's power cycle is the process killed (SIGKILL: nothing flushed that a power
cut would not flush) and started again on the same working directory, whose ``parameters.bson`` is the
board's storage.  The command line and environment are kept in ``px4.json`` in that directory, the pid in
``px4.pid``, the firmware's output appended to ``px4.log``.

    python -m magline.sitl.px4_power on|off --workdir DIR
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

SIM_MODEL = "none_iris"  # PX4's airframe without a simulator of its own: its sensors come over HIL_SENSOR


class Px4Process:
    """The SITL process of one working directory."""

    def __init__(self, workdir: Path) -> None:
        self.workdir = workdir
        self.pidfile = workdir / "px4.pid"

    @classmethod
    def prepare(cls, build: Path, workdir: Path, env: dict[str, str] | None = None,
                etc: Path | None = None) -> Px4Process:
        """Write how to start PX4 from ``build`` (``build/px4_sitl_default``) in ``workdir``; ``etc``: a
        startup folder other than the build's own."""
        workdir.mkdir(parents=True, exist_ok=True)
        spec = {"argv": [str(build / "bin" / "px4"), "-d", "-w", str(workdir), str(etc or build / "etc")],
                "env": {"PX4_SIM_MODEL": SIM_MODEL, **(env or {})}}
        (workdir / "px4.json").write_text(json.dumps(spec, indent=2) + "\n")
        return cls(workdir)

    def pid(self) -> int | None:
        try:
            pid = int(self.pidfile.read_text())
        except (OSError, ValueError):
            return None
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return None
        return pid

    def on(self) -> None:
        if self.pid() is not None:
            return
        spec = json.loads((self.workdir / "px4.json").read_text())
        with open(self.workdir / "px4.log", "ab") as log:
            proc = subprocess.Popen(spec["argv"], cwd=self.workdir, env={**os.environ, **spec["env"]}, stdout=log,
                                    stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, start_new_session=True)
        self.pidfile.write_text(f"{proc.pid}\n")

    def off(self, timeout_s: float = 10.0) -> None:
        pid = self.pid()
        if pid is None:
            return
        os.kill(pid, signal.SIGKILL)
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            try:
                waited, _ = os.waitpid(pid, os.WNOHANG)  # ours: reap it; another's: the init reaps it
            except ChildProcessError:
                waited = 0
            if waited or self.pid() is None:
                break
            time.sleep(0.05)
        self.pidfile.unlink(missing_ok=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m magline.sitl.px4_power", description=__doc__.split("\n")[0])
    parser.add_argument("state", choices=("on", "off"))
    parser.add_argument("--workdir", type=Path, required=True)
    args = parser.parse_args(argv)
    if not (args.workdir / "px4.json").is_file():
        print(f"no px4.json in {args.workdir}: the runner writes it before the first power-on", file=sys.stderr)
        return 2
    process = Px4Process(args.workdir)
    process.on() if args.state == "on" else process.off()
    return 0


if __name__ == "__main__":
    sys.exit(main())
