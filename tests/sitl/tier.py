"""What each firmware's SITL-tier test does: find the build, run the firmware's runner, hold every check."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

CACHE = Path.home() / ".cache" / "magline" / "sitl"


def run_runner(module: str, build_flag: str, build: Path, missing: str, tmp_path: Path) -> None:
    """Run ``python -m module build_flag build`` in ``tmp_path`` and fail, in one line per check, on every
    check that does not hold; ``missing`` when the build is not there (this tier exists to be run)."""
    if not build.exists():
        pytest.fail(missing, pytrace=False)
    out = tmp_path / "checks.json"
    run = subprocess.run([sys.executable, "-m", module, build_flag, str(build), "--workdir", str(tmp_path),
                          "--json", str(out)], capture_output=True, text=True, timeout=900)
    print(run.stdout, run.stderr)
    if not out.is_file():
        pytest.fail(f"{module} wrote no checks (exit {run.returncode}): {run.stderr.strip()[-500:]}", pytrace=False)
    checks = json.loads(out.read_text())["checks"]
    failed = [f"{unit}: {c['name']} = {c['figure']} (wanted {c['tolerance']})"
              for unit, rows in checks.items() for c in rows if not c["holds"]]
    assert not failed and run.returncode == 0, "\n".join(failed) or run.stderr
