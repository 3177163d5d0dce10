"""What every SITL runner shares: a check's line in the summary, the private network namespace a SITL
runs in, and the record of a station run read back as ``magline show`` gives it."""

from __future__ import annotations

import argparse
import json
import os
import shutil
import struct
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import yaml
from pymavlink import mavutil

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
              json_path: Path | None, only: list[str] | None = None) -> int:
    """Run each labelled unit (those in ``only``, when given) in its own folder under ``workdir``, print the
    one-page summary (the firmware version the station saw, then every check), write it to ``json_path`` too,
    and return the runner's exit code: 0 when every check holds; 2 for a unit the runner does not have."""
    unknown = sorted(set(only or ()) - set(units))
    if unknown:
        print(f"no unit {', '.join(unknown)} in this runner: it has {', '.join(units)}", file=sys.stderr)
        return 2
    firmware = None
    lines, results = [], {}
    for label, unit in units.items():
        if only and label not in only:
            continue
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


INTEGER_TYPES = (mavutil.mavlink.MAV_PARAM_TYPE_INT8, mavutil.mavlink.MAV_PARAM_TYPE_INT16,
                 mavutil.mavlink.MAV_PARAM_TYPE_INT32, mavutil.mavlink.MAV_PARAM_TYPE_UINT8,
                 mavutil.mavlink.MAV_PARAM_TYPE_UINT16, mavutil.mavlink.MAV_PARAM_TYPE_UINT32)


def param_value(msg, bytewise: bool) -> float:
    """A PARAM_VALUE's value: PX4 sends an integer's bytes in the float field (its bytewise encoding; 2 then
    reads 2.8e-45 as a float), ArduPilot the integer cast to a float."""
    if bytewise and msg.param_type in INTEGER_TYPES:
        return float(struct.unpack("<i", struct.pack("<f", msg.param_value))[0])
    return float(msg.param_value)


def read_params(link: mavutil.mavfile, names: list[str], timeout_s: float = 60.0,
                bytewise: bool = False) -> dict[str, float]:
    """``names`` as the firmware holds them now, asked over ``link`` (a pymavlink link that heard a heartbeat)
    until each has answered; ``bytewise``: integers come as their bytes (PX4)."""
    values: dict[str, float] = {}
    deadline = time.monotonic() + timeout_s
    while len(values) < len(names):
        if time.monotonic() > deadline:
            raise RuntimeError(f"the firmware did not answer for {sorted(set(names) - set(values))}")
        for name in names:
            if name not in values:
                link.mav.param_request_read_send(link.target_system, link.target_component, name.encode(), -1)
        ends = time.monotonic() + 1.0
        while time.monotonic() < ends:
            msg = link.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.2)
            if msg is not None and msg.param_id in names:
                values[msg.param_id] = param_value(msg, bytewise)
    return values


def runner_parser(module: str, doc: str, build_flag: str, build_help: str) -> argparse.ArgumentParser:
    """A runner's command line: where its firmware build is, and the options every runner has."""
    parser = argparse.ArgumentParser(prog=f"python -m {module}", description=doc.split("\n")[0])
    parser.add_argument(build_flag, type=Path, required=True, help=build_help)
    parser.add_argument("--workdir", type=Path, help="where each unit's files stay (default: a temporary folder)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--json", type=Path, help="write every check here")
    parser.add_argument("--unit", action="append", metavar="NAME",
                        help="run only this unit of the runner's (again for more; default: every one)")
    return parser


MATRIX_GOAL = 0.002  # the tier's goal for every element of a written soft-iron matrix
OFFSET_GOAL_MG = 0.5  # and for every axis of a written offset


def fit_sigmas(record: dict, device_id: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The σ the station states for a compass's offset (µT, per axis) and soft-iron matrix (per element):
    the primary's, or that of the compass with ``device_id``."""
    calibration = record.get("calibration") or {}
    prefix = ""
    for sensor in (record.get("unit_info") or {}).get("magnetometers") or []:
        if device_id is not None and int(sensor.get("device_id") or 0) == int(device_id):
            prefix = str(sensor.get("prefix") or "")
    fit = calibration if not prefix else calibration["magnetometers"][prefix.rstrip(".")]
    return np.asarray(fit["hard_iron_sigma_ut"], float), np.asarray(fit["soft_iron_sigma"], float)


def true_to_sigma(name: str, errors: np.ndarray, sigmas: np.ndarray, unit: str, goal: float,
                  quantum: float = 0.0) -> Check:
    """A written calibration against the truth.  Every element's error must lie within 3σ of the σ the
    station states for it (plus the firmware's own rounding, ``quantum``): the station is right about
    what it knows; whether that meets the tier's goal is said beside.  Why not the goal itself: a tumble
    the station judged determined at 60 % coverage leaves an axis known to ±3 mG, and it says so."""
    errors, sigmas = np.abs(np.ravel(errors)), np.ravel(sigmas)
    worst = int(np.argmax(errors / np.maximum(sigmas, 1e-12)))
    holds = bool(np.all(errors <= TRUE_TO_SIGMA * sigmas + quantum))
    met = "met" if float(errors.max()) <= goal and float(TRUE_TO_SIGMA * sigmas.max()) <= goal else "not met"
    figure = f"max |Δ| {errors.max():.4g} {unit} ({errors[worst] / max(sigmas[worst], 1e-12):.1f}σ)"
    return Check(f"{name} after a power cut", figure, f"≤ {TRUE_TO_SIGMA:g}σ; {goal:g} {unit} goal {met}".strip(),
                 holds)


MATRIX_ELEMENTS = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))  # diagonal, then xy, xz, yz


def calibration_checks(record: dict, device_id: int | None, offsets_mg: tuple[np.ndarray, np.ndarray],
                       matrix: tuple[np.ndarray, np.ndarray], names: tuple[str, str],
                       offset_quantum_mg: float = 0.0) -> list[Check]:
    """A compass's written offset (mG: kept after the power cut, and the truth) and its soft-iron matrix
    (the six elements of :data:`MATRIX_ELEMENTS`, kept and truth), each held to the σ the station states."""
    hard_sigma_ut, soft_sigma = fit_sigmas(record, device_id)
    (kept_mg, truth_mg), (kept_m, truth_m) = offsets_mg, matrix
    element_sigma = np.array([soft_sigma[i, j] for i, j in MATRIX_ELEMENTS])
    return [true_to_sigma(names[0], np.asarray(kept_mg) - truth_mg, hard_sigma_ut * 10.0, "mG", OFFSET_GOAL_MG,
                          offset_quantum_mg),
            true_to_sigma(names[1], np.asarray(kept_m) - truth_m, element_sigma, "", MATRIX_GOAL)]
