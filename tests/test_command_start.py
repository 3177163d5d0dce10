"""A command imports what it uses (issue 65): ``magline --help`` and ``magline check`` answer before the
fit's SciPy and the results store's SQLAlchemy are imported — together most of a second of a command's
start.  Measured, not timed here: ``python benchmarks/cli_start.py`` prints each command's start."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from conftest import REPO

# the fit's SciPy, the store's SQLAlchemy, the tumble and the mounting checks (registered through thin hook
# modules that import them on the first unit), pymavlink's tables
HEAVY = ("scipy", "sqlalchemy", "magline.core.acquisition.tumble", "magline.core.mounting.checks", "pymavlink")
PROBE = """
import json, sys, io, contextlib
sys.argv = ["magline", *json.loads(sys.argv[1])]
from magline.core.entry import main
with contextlib.redirect_stdout(io.StringIO()):
    try:
        code = main()
    except SystemExit as exc:
        code = exc.code
print(json.dumps({"code": code, "modules": sorted(sys.modules)}))
"""


def imported_by(*argv: str) -> tuple[int, set[str]]:
    done = subprocess.run([sys.executable, "-c", PROBE, json.dumps(list(argv))], cwd=REPO, capture_output=True,
                          text=True, timeout=120, check=True)
    found = json.loads(done.stdout.strip().splitlines()[-1])
    return found["code"], {name.split(".")[0] for name in found["modules"]} | set(found["modules"])


# what reading a station file needs beside them: its YAML and the options models (pydantic); the arithmetic's
# NumPy it does not (a tenth of a second of a command's start), and the help text needs none of the three
NOT_FOR_HELP = ("numpy", "pydantic", "yaml")


@pytest.mark.parametrize("argv", [("--help",), ("check", "stations/demo.yaml"), ("check", "stations/px4-sim.yaml"),
                                  ("check", "stations/helmholtz-sim.yaml"), ("check", "stations/turntable-sim.yaml")])
def test_a_command_that_needs_no_fit_and_no_store_imports_neither(argv):
    code, modules = imported_by(*argv)
    assert code == 0
    assert not modules & set(HEAVY), f"magline {' '.join(argv)} imported {sorted(modules & set(HEAVY))}"
    assert "numpy" not in modules, f"magline {' '.join(argv)} imported NumPy"


def test_the_help_imports_no_station_reading_and_no_arithmetic():
    """``magline --help`` lists the plugins' commands without their registrations (their options models)."""
    code, modules = imported_by("--help")
    assert code == 0
    assert not modules & set(NOT_FOR_HELP), f"magline --help imported {sorted(modules & set(NOT_FOR_HELP))}"
    assert "sim" in subprocess.run([sys.executable, "-m", "magline.core.entry", "--help"], cwd=REPO, text=True,
                                   capture_output=True, timeout=120, check=True).stdout  # a plugin's command


# every built-in plugin's options model, or the module holding it with its factory
OPTIONS_MODULES = {"mock": "magline.plugins.mock.options", "px4": "magline.plugins.px4.options",
                   "ardupilot": "magline.plugins.ardupilot.options", "inav": "magline.plugins.inav.options",
                   "helmholtz": "magline.plugins.helmholtz.options", "gimbal": "magline.plugins.gimbal.motion",
                   "turntable": "magline.plugins.turntable.motion", "command": "magline.plugins.power.command",
                   "scpi-supply": "magline.plugins.power.scpi_supply", "usb-hub": "magline.plugins.power.usb_hub",
                   "electronic-load": "magline.plugins.current.electronic_load",
                   "motor-test": "magline.plugins.current.motor_test"}


@pytest.mark.parametrize(("station", "uses"), [("stations/demo.yaml", {"mock"}),
                                               ("stations/px4-sim.yaml", {"px4"}),
                                               ("stations/helmholtz-sim.yaml", {"helmholtz", "mock"}),
                                               ("stations/turntable-sim.yaml", {"turntable", "px4"})])
def test_check_imports_the_options_models_of_the_plugins_its_station_names_and_no_other(station, uses):
    code, modules = imported_by("check", station)
    assert code == 0
    assert {name for name, module in OPTIONS_MODULES.items() if module in modules} == uses


def test_the_commands_that_use_them_still_find_them():
    """The probe sees imports: ``magline fit`` imports SciPy's optimiser on use, and ``history`` the store."""
    code, modules = imported_by("fit", "--help")
    assert code == 0 and "scipy" not in modules  # its help alone needs neither
    code, modules = imported_by("history", "NO-SUCH-UNIT", "--station", "stations/demo.yaml")
    assert "sqlalchemy" in modules



def test_a_unit_run_judges_its_statistics_without_scipy_stats(make_station, tmp_path):
    """A unit's fit, drift test and settling test take their quantiles from ``scipy.special`` (a third of a
    second of CPU less at every ``magline run``, the running fit's first drift test no longer waiting for it)."""
    # the mock's storage in this test's folder: the probe runs in the checkout
    station = make_station({"products": {"MOCK-100": {"options": {"storage": str(tmp_path / "storage.json")}}}})
    code, modules = imported_by("run", str(station), "--serial", "IMPORTS-1")
    assert code == 0
    assert "scipy.optimize" in modules and "magline.core.fit.geometric" in modules  # the unit was fitted …
    assert "scipy.stats" not in modules  # … and judged without scipy.stats
