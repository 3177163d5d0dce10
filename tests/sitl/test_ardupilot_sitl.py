"""The SITL tier for ArduPilot: the real ``magline run`` on ArduCopter's own SITL build, held to a known truth.

Deselected by default (``pytest -m sitl`` runs it; no CI run selects it): it needs the ArduPilot tree
ArduCopter's SITL was built in, named by ``MAGLINE_SITL_ARDUPILOT`` (default
``~/.cache/magline/sitl/ardupilot``, holding ``build/sitl/bin/arducopter``).  A missing build fails the test
in one line: this tier exists to be run.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from tier import CACHE, run_runner


@pytest.mark.sitl
def test_good_units_pass_and_a_turned_mast_compass_fails_on_arducopter_s_own_sitl(tmp_path):
    source = Path(os.environ.get("MAGLINE_SITL_ARDUPILOT", CACHE / "ardupilot"))
    binary = source / "build" / "sitl" / "bin" / "arducopter"
    run_runner("magline.sitl.ardupilot_run", "--source", source if binary.is_file() else binary,
               f"ArduCopter's SITL is not built: no {binary} (set MAGLINE_SITL_ARDUPILOT to the ArduPilot tree it "
               "was built in)", tmp_path)
