"""The SITL tier for INAV: the real ``magline run`` on INAV's own SITL build, held to a known truth.

Deselected by default (``pytest -m sitl`` runs it; no CI run selects it): it needs a SITL binary built from
INAV's own tree, named by ``MAGLINE_SITL_INAV`` (default ``~/.cache/magline/sitl/inav/SITL.elf``).  A
missing build fails the test in one line: this tier exists to be run.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from tier import CACHE, run_runner


@pytest.mark.sitl
def test_a_good_unit_passes_and_a_turned_compass_fails_on_inav_s_own_sitl(tmp_path):
    binary = Path(os.environ.get("MAGLINE_SITL_INAV", CACHE / "inav" / "SITL.elf"))
    run_runner("magline.sitl.inav_run", "--sitl", binary, f"INAV's SITL is not built: no {binary} (set "
               "MAGLINE_SITL_INAV to its SITL.elf)", tmp_path)
