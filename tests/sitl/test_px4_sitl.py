"""The SITL tier for PX4: the real ``magline run`` on PX4's own SITL build, held to a known truth.

Deselected by default (``pytest -m sitl`` runs it; no CI run selects it): it needs PX4's build folder of
the ``px4_sitl_default`` target, named by ``MAGLINE_SITL_PX4`` (default
``~/.cache/magline/sitl/px4/px4_sitl_default``).  A missing build fails the test in one line: this tier
exists to be run.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from tier import CACHE, run_runner


@pytest.mark.sitl
def test_a_good_unit_passes_and_a_turned_compass_fails_on_px4_s_own_sitl(tmp_path):
    build = Path(os.environ.get("MAGLINE_SITL_PX4", CACHE / "px4" / "px4_sitl_default"))
    run_runner("magline.sitl.px4_run", "--build", build, f"PX4's SITL is not built: no {build / 'bin' / 'px4'} "
               "(set MAGLINE_SITL_PX4 to the px4_sitl_default build folder)", tmp_path)
