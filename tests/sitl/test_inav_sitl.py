"""The SITL tier for INAV: the real ``magline run`` on INAV's own SITL build, held to a known truth.

Deselected by default (``pytest -m sitl`` runs it; no CI run selects it): it needs a SITL binary built from
INAV's own tree, named by ``MAGLINE_SITL_INAV`` (default ``~/.cache/magline/sitl/inav/SITL.elf``).  A
missing build fails the test in one line: this tier exists to be run.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

DEFAULT = Path.home() / ".cache" / "magline" / "sitl" / "inav" / "SITL.elf"


@pytest.mark.sitl
def test_a_good_unit_passes_and_a_turned_compass_fails_on_inav_s_own_sitl(tmp_path):
    binary = Path(os.environ.get("MAGLINE_SITL_INAV", DEFAULT))
    if not binary.is_file():
        pytest.fail(f"INAV's SITL is not built: no {binary} (set MAGLINE_SITL_INAV to its SITL.elf)", pytrace=False)
    out = tmp_path / "checks.json"
    run = subprocess.run([sys.executable, "-m", "magline.sitl.inav_run", "--sitl", str(binary), "--workdir",
                          str(tmp_path), "--json", str(out)], capture_output=True, text=True, timeout=600)
    print(run.stdout, run.stderr)
    checks = json.loads(out.read_text())["checks"]
    failed = [f"{unit}: {c['name']} = {c['figure']} (wanted {c['tolerance']})"
              for unit, rows in checks.items() for c in rows if not c["holds"]]
    assert not failed and run.returncode == 0, "\n".join(failed) or run.stderr
