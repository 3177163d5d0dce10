"""What every SITL runner shares: a check's line in the summary, the private network namespace a SITL
runs in, and the record of a station run read back as ``magline show`` gives it."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import yaml

PRIVATE = "MAGLINE_SITL_NETNS"  # set in the namespace a runner re-executes itself in


@dataclass
class Check:
    """One line of a runner's summary: what was checked, the figure seen, what it is held to."""

    name: str
    figure: str
    tolerance: str
    holds: bool

    def line(self) -> str:
        return f"{'ok  ' if self.holds else 'FAIL'} {self.name:<34} {self.figure:<28} {self.tolerance}"


def in_private_network(module: str, argv: list[str]) -> str | None:
    """Re-execute ``python -m module argv`` in a private network namespace with only loopback up (a SITL
    that listens on every interface stays off the network); returns only inside it — or a reason it
    cannot, for the caller to print."""
    if os.environ.get(PRIVATE) != "1":
        if shutil.which("unshare") is None:
            return "unshare (util-linux) is needed to run the SITL in a private network namespace"
        os.execvpe("unshare", ["unshare", "-n", sys.executable, "-m", module, *argv], {**os.environ, PRIVATE: "1"})
    subprocess.run(["ip", "link", "set", "lo", "up"], check=True)
    return None


def magline(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    """The real command line, as an engineer runs it."""
    return subprocess.run([sys.executable, "-m", "magline.core.cli", *args], cwd=cwd, capture_output=True,
                          text=True, stdin=subprocess.DEVNULL)


def last_record(station: Path, cwd: Path) -> dict:
    """The station's last unit, as ``magline show --json`` prints it."""
    shown = magline("show", "1", "--station", str(station), "--json", cwd=cwd)
    if shown.returncode != 0:
        raise RuntimeError(f"magline show failed: {shown.stderr.strip()}")
    return json.loads(shown.stdout)


def measurement(record: dict, name: str) -> float | None:
    return next((m["value"] for m in record.get("measurements", []) if m["name"] == name), None)


def summarise(title: str, workdir: Path, units: dict[str, Callable[[Path], tuple[dict, list[Check]]]],
              json_path: Path | None) -> int:
    """Run each labelled unit in its own folder under ``workdir``, print the one-page summary (the firmware
    version the station saw, then every check), write it to ``json_path`` too, and return the runner's
    exit code: 0 when every check holds."""
    firmware = None
    lines, results = [], {}
    for label, unit in units.items():
        record, checks = unit((workdir / label).resolve())
        if firmware is None:
            firmware = (record.get("unit_info") or {}).get("firmware", "?")
        results[label] = [asdict(c) for c in checks]
        lines += [f"[{label}] {c.line()}" for c in checks]
    print(f"{title} — firmware the station saw: {firmware}; files in {workdir}")
    print("\n".join(lines))
    if json_path:
        json_path.write_text(json.dumps({"firmware": firmware, "checks": results}, indent=2) + "\n")
    return 0 if all(c["holds"] for checks in results.values() for c in checks) else 1


def run_station(station: Path, serial: str, workdir: Path) -> tuple[dict, float]:
    """``magline run`` of one unit as an operator starts it: its record and how long it took (s); what it
    printed is kept in ``run.log`` beside it."""
    started = time.monotonic()
    run = magline("run", str(station), "--serial", serial, cwd=workdir)
    cycle_s = time.monotonic() - started
    (workdir / "run.log").write_text(run.stdout + run.stderr)
    return last_record(station, workdir), cycle_s


MOUNTING_GOAL_DEG = 1.0  # the tier's goal for a good unit's mounting error
INCLINATION_LIMIT_DEG = 2.0
TRUE_TO_SIGMA = 3.0  # a figure is true to its σ when the truth lies within 3σ of it


def station_figures(record: dict, cycle_s: float) -> list[Check]:
    """A good unit's figures from the station's own record.  The mounting error (the truth: 0°) must lie
    within 3σ of the σ the station states for it — the station is right about what it knows; whether it
    knows it to the tier's 1° goal is said beside.  Why not held to 1° itself: a stream that pairs few
    readings (INAV's compass at 10 Hz) leaves a σ near 1°, and a check that fails a quarter of good runs
    says nothing about the station.  The inclination error is held to 2°; the cycle time is a figure."""
    checks = []
    error, sigma = measurement(record, "mounting_error_deg"), measurement(record, "mounting_sigma_deg")
    if error is None or sigma is None:
        checks.append(Check("mounting_error_deg", "missing", f"|·| ≤ {TRUE_TO_SIGMA:g}σ", False))
    else:
        goal = "met" if abs(error) <= MOUNTING_GOAL_DEG and TRUE_TO_SIGMA * sigma <= MOUNTING_GOAL_DEG else "not met"
        checks.append(Check("mounting_error_deg", f"{error:.2f}° ± {sigma:.2f}°",
                            f"|·| ≤ {TRUE_TO_SIGMA:g}σ; {MOUNTING_GOAL_DEG:g}° goal {goal}",
                            abs(error) <= TRUE_TO_SIGMA * sigma))
    value = measurement(record, "inclination_error_deg")
    checks.append(Check("inclination_error_deg", "missing" if value is None else f"{value:.2f}°",
                        f"|·| ≤ {INCLINATION_LIMIT_DEG}°", value is not None and abs(value) <= INCLINATION_LIMIT_DEG))
    return [*checks, Check("cycle time", f"{cycle_s:.1f} s", "(figure)", True)]


def write_station(shipped: str, workdir: Path, field_ut: float, inclination_deg: float, product: dict,
                  station: dict | None = None) -> Path:
    """The shipped station file ``shipped`` (under ``stations/``) pointed at a SITL: its product's keys
    replaced by ``product``, its top-level keys by ``station``, the field reference the truth's, its results
    in ``results.sqlite`` beside it."""
    path = Path(__file__).resolve().parent.parent / "stations" / shipped
    config = yaml.safe_load(path.read_text())
    next(iter(config["products"].values())).update(product)
    config |= station or {}
    config["field_source"] = {"type": "fixed", "options": {"field_ut": field_ut, "inclination_deg": inclination_deg}}
    config["results"] = {"sink": "sqlite", "path": "results.sqlite"}
    written = workdir / "station.yaml"
    written.write_text(yaml.safe_dump(config, sort_keys=False))
    return written
