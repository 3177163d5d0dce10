"""Installed layout: everything under ``magline``; nothing named bare ``core`` or ``plugins``."""

from __future__ import annotations

import subprocess
import sys
import zipfile

from conftest import REPO


def test_wheel_contains_only_the_magline_namespace(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
                           "-w", str(tmp_path), str(REPO)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    wheel = next(tmp_path.glob("magline-*.whl"))
    names = zipfile.ZipFile(wheel).namelist()
    tops = {n.split("/")[0] for n in names}
    assert tops <= {"magline", next(n.split("/")[0] for n in names if ".dist-info/" in n)}
    for required in ("magline/core/hookspecs.py", "magline/plugin/__init__.py", "magline/plugins/mock/dut.py",
                     "magline/stations/demo.yaml",
                     "magline/sim/vehicle.py", "magline/sim/truth/imu.py", "magline/sim/commands.py",
                     "magline/core/fit/geometric.py", "magline/core/results/migrations/env.py",
                     "magline/core/results/migrations/versions/0002_run_uuid.py"):
        assert required in names
    assert not any(n.startswith(("core/", "plugins/", "sim/")) for n in names)
    assert not any(n.startswith("magline/plugins/mock/sim") for n in names)  # the simulators have their own root


def test_importable_names():
    import magline.core
    import magline.plugins.mock
    import magline.sim

    assert magline.core.__file__ and magline.plugins.mock.__file__ and magline.sim.__file__
