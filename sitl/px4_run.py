"""A good PX4 unit, and one whose compass is turned, through the real ``magline run`` on PX4's own SITL.

The firmware is fed by :mod:`magline.sitl.px4_hil` (a compass of known distortion, tumbled, over
``HIL_SENSOR``); the station is the shipped ``stations/px4-sim.yaml`` pointed at the SITL, its power cycle
the process killed and started again on the same storage (:mod:`magline.sitl.px4_power`).  After the run
the power is cut once more, and the calibration PX4 kept is read over MAVLink and held to the truth.  The
whole run happens in a private network namespace (``unshare -n``): PX4's MAVLink and simulator ports
are then reachable on loopback only.

    python -m magline.sitl.px4_run --build PATH/TO/build/px4_sitl_default [--workdir DIR] [--seed 1]
                                   [--turned 90] [--json OUT]

Prints one line per check (figure against tolerance) and exits 0 when every one holds.
"""

from __future__ import annotations

import json
import sys
import tempfile
import threading
from dataclasses import asdict
from pathlib import Path

import numpy as np
import yaml
from pymavlink import mavutil

from magline.sim.load import LoadSim
from magline.sitl.checks import (
    Check,
    calibration_checks,
    in_private_network,
    read_params,
    run_station,
    runner_parser,
    station_figures,
    summarise,
    write_station,
)
from magline.sitl.px4_hil import BatteryReporter, HilFeeder, Px4Truth
from magline.sitl.px4_power import Px4Process

STATION_LINK = "udpin://0.0.0.0:14550"  # PX4's ground-station link sends to port 14550 on the host
# The compass HIL_SENSOR id 0 feeds (``simulator_mavlink``'s first PX4Magnetometer).  The station names it: a posix
# build's MAVLink shell echoes a command and runs none, so it cannot say which sensor SCALED_IMU carries, and
# PX4's posix startup presets CAL_MAG0_ID and CAL_MAG1_ID for both simulated compasses
HIL_MAG0_DEVICE_ID = 197388
PARAM_LINK = "udpin:0.0.0.0:14550"  # the same port, read by pymavlink once the station is done


def station_file(workdir: Path, truth: Px4Truth, product: dict | None = None, station: dict | None = None) -> Path:
    """The shipped PX4 station pointed at the SITL in ``workdir`` (its power the process's own cut), the
    truth's site and field; ``product``: more of the product's keys (``persist``, …); ``station``: more
    top-level keys (``current_source``, …)."""
    power = [sys.executable, "-m", "magline.sitl.px4_power"]
    site = {"latitude_deg": truth.latitude_deg, "longitude_deg": truth.longitude_deg, "altitude_m": truth.altitude_m}
    shipped = yaml.safe_load((Path(__file__).resolve().parent.parent / "stations" / "px4-sim.yaml").read_text())
    options = {**next(iter(shipped["products"].values())).get("options", {}), "connect_timeout_s": 60,
               "boot_timeout_s": 60}
    return write_station("px4-sim.yaml", workdir, truth.field_ut, truth.inclination_deg, {
        "connection": STATION_LINK, "magnetometer": HIL_MAG0_DEVICE_ID, "options": options,
        "power": {"method": "command", "options": {"off": [*power, "off", "--workdir", str(workdir)],
                                                   "on": [*power, "on", "--workdir", str(workdir)],
                                                   "off_time_s": 0.5}}, **(product or {})},
        {"station": {**shipped["station"], "location": site}, **(station or {})})


def read_px4_params(names: list[str], timeout_s: float = 60.0) -> dict[str, float]:
    """``names`` as PX4 holds them now, over its ground-station link."""
    link = mavutil.mavlink_connection(PARAM_LINK, source_system=245, source_component=190)
    try:
        if link.wait_heartbeat(timeout=timeout_s) is None:
            raise RuntimeError(f"PX4 sent no heartbeat within {timeout_s:g} s after the power came back")
        return read_params(link, names, timeout_s, bytewise=True)
    finally:
        link.close()


def _fresh(workdir: Path) -> None:
    """A new board: no parameters kept, no results from an earlier run in this folder."""
    workdir.mkdir(parents=True, exist_ok=True)
    for stale in ("parameters.bson", "parameters_backup.bson", "results.sqlite"):
        (workdir / stale).unlink(missing_ok=True)


def _run_and_keep(px4: Px4Process, feeder: HilFeeder, station: Path, serial: str,
                  names: list[str]) -> tuple[dict, float, dict[str, float]]:
    """One unit on PX4's SITL fed by ``feeder``: ``magline run`` of the station, a hard power cut, and
    ``names`` read back from what the board kept."""
    threading.Thread(target=feeder.serve, daemon=True).start()
    try:
        px4.on()
        record, cycle_s = run_station(station, serial, px4.workdir)
        px4.off()  # the hard power cut: what was saved is what the unit keeps
        px4.on()
        kept = read_px4_params(names)
    finally:
        px4.off()
        feeder.stop()
    return record, cycle_s, kept


def one_unit(build: Path, workdir: Path, seed: int, turned_deg: float) -> tuple[dict, list[Check]]:
    """Run one unit on a fresh board; its compass sits at ``turned_deg`` of yaw (0: where PX4 expects it)."""
    _fresh(workdir)
    truth = Px4Truth.drawn(seed, mounting_yaw_deg=turned_deg)
    (workdir / "truth.json").write_text(json.dumps(asdict(truth), indent=2) + "\n")
    slots = [f"CAL_MAG{n}_{k}" for n in range(4) for k in ("ID", *truth.expected)]
    record, cycle_s, kept = _run_and_keep(Px4Process.prepare(build, workdir), HilFeeder(truth, seed=seed),
                                          station_file(workdir, truth), f"SITL-PX4-{seed}", slots)
    return record, _judge(truth, record, kept, cycle_s, turned=bool(turned_deg))


# The sweep of the shipped interference station (stations/interference-sim.yaml) and ArduPilot's bands
SWEEP = {"steps": 2, "settle_s": 0.3, "readings": 8, "compensation_goal_pct": 5.0, "compensation_budget_s": 9.5}
SWEEP_LIMITS = {"interference_pct_at_max": {"le": 60.0, "marginal": 30.0}}
CURRENT_MAX_A = 40.0
PER_AMP_GOAL_MG, PER_AMP_GOAL_SHARE = 0.5, 0.03  # the tier's goal for a written compensation: 0.5 mG/A + 3 %


def swept_unit(build: Path, workdir: Path, seed: int) -> tuple[dict, list[Check]]:
    """A good unit whose compass follows the battery current: calibrated, swept, compensated and proven in
    one run, the current drawn by a simulated electronic load and told to PX4 by the feeder's power module
    (PX4 started with ``SIM_BAT_ENABLE = 0``: its own simulated battery would compete)."""
    _fresh(workdir)
    per_amp = np.random.default_rng(seed + 1000).uniform(-0.12, 0.12, 3).round(4).tolist()  # ≤ 17 % at 40 A
    truth = Px4Truth.drawn(seed, interference_ut_per_a=per_amp)
    (workdir / "truth.json").write_text(json.dumps(
        {**asdict(truth), "expected_compensation": truth.expected_compensation()}, indent=2) + "\n")
    load = LoadSim("tcp:127.0.0.1:0").start()
    battery = BatteryReporter(load.sinking_current).start()
    feeder = HilFeeder(truth, seed=seed, current_a=load.sinking_current, held=lambda: load.input_on)
    station = station_file(workdir, truth, {"interference": "compensate", "current_max_a": CURRENT_MAX_A,
                                            "limits": {"hard_iron_norm_ut": {"le": 150.0}, **SWEEP_LIMITS}},
                           {"current_source": {"type": "electronic-load", "options": {"resource": load.visa_resource}},
                            "interference": SWEEP})

    slots = [f"CAL_MAG{n}_{k}" for n in range(4) for k in ("ID", *truth.expected, "XCOMP", "YCOMP", "ZCOMP")]
    try:
        record, cycle_s, kept = _run_and_keep(
            Px4Process.prepare(build, workdir, env={"PX4_PARAM_SIM_BAT_ENABLE": "0"}), feeder, station,
            f"SITL-PX4-MOT-{seed}", [*slots, "CAL_MAG_COMP_TYP"])
    finally:
        battery.stop()
        load.stop()
    return record, [*_judge(truth, record, kept, cycle_s, turned=False), *_compensation_checks(truth, record, kept)]


def _compensation_checks(truth: Px4Truth, record: dict, kept: dict[str, float]) -> list[Check]:
    """The current compensation kept after the power cut, against minus the raw field change per amp."""
    expected = truth.expected_compensation()
    p = f"CAL_MAG{_slot(record, kept)}_"
    want = np.array([expected[f"{a}COMP"] for a in "XYZ"])
    error = float(np.linalg.norm(np.array([kept[f"{p}{a}COMP"] for a in "XYZ"]) - want))
    allowed = PER_AMP_GOAL_MG + PER_AMP_GOAL_SHARE * float(np.linalg.norm(want))
    return [Check("CAL_MAG_COMP_TYP after a power cut", f"{kept['CAL_MAG_COMP_TYP']:g}", "2 (current, instance 0)",
                  kept["CAL_MAG_COMP_TYP"] == expected["COMP_TYP"]),
            Check(f"{p}X/Y/ZCOMP after a power cut", f"|Δ| {error:.3f} mG/A", f"≤ {allowed:.3f} mG/A (0.5 + 3 %)",
                  error <= allowed)]


def _slot(record: dict, kept: dict[str, float]) -> int:
    """The slot PX4 holds the unit's compass in (by its device id), 0 when none does yet."""
    device_id = (record.get("unit_info") or {}).get("selected_sensor")
    for n in range(4):
        if device_id and int(kept[f"CAL_MAG{n}_ID"]) == int(device_id):
            return n
    return 0


def _judge(truth: Px4Truth, record: dict, kept: dict[str, float], cycle_s: float, turned: bool) -> list[Check]:
    verdict, cause = record.get("verdict"), record.get("cause") or ""
    slot = _slot(record, kept)
    if turned:
        written = (record.get("params") or {}).get("written") or {}
        untouched = all(kept[f"CAL_MAG{slot}_{a}OFF"] == 0.0 for a in "XYZ")
        return [Check("turned compass FAILs naming its fix", f"{verdict}: {cause[:60]}", "FAIL, 'CAL_MAG'",
                      verdict == "fail" and "CAL_MAG" in cause),
                Check("nothing written to a failed unit", f"{len(written)} written, offsets "
                      f"{'0' if untouched else 'changed'}", "none written, offsets 0", not written and untouched)]
    checks = [Check("good unit PASSes", f"{verdict} {cause[:40]}", "pass", verdict == "pass")]
    p = f"CAL_MAG{slot}_"
    offsets = (np.array([kept[f"{p}{a}OFF"] for a in "XYZ"]) * 1000.0,
               np.array([truth.expected[f"{a}OFF"] for a in "XYZ"]) * 1000.0)
    matrix = ("XSCALE", "YSCALE", "ZSCALE", "XODIAG", "YODIAG", "ZODIAG")  # as MATRIX_ELEMENTS orders them
    elements = (np.array([kept[p + k] for k in matrix]), np.array([truth.expected[k] for k in matrix]))
    checks += calibration_checks(record, int(kept[f"{p}ID"]) or None, offsets, elements,
                                 (f"{p}X/Y/ZOFF", f"{p}SCALE/ODIAG"))
    # the station's proof that the firmware applies the calibration (HIGHRES_IMU beside the raw readings) ran
    # and held: HIGHRES_IMU is the output less EKF2's bias estimate, which the proof must allow for
    proof = ((record.get("persistence") or {}).get("figures") or {})
    difference, tolerance = proof.get("applied_difference_ut"), proof.get("applied_tolerance_ut")
    checks.append(Check("firmware applies it (HIGHRES_IMU)",
                        "not run" if difference is None else f"{difference:.2f} µT apart", "proven, within "
                        + ("its tolerance" if tolerance is None else f"{tolerance:.2f} µT"),
                        difference is not None and tolerance is not None and difference <= tolerance))
    return [*checks, *station_figures(record, cycle_s)]


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = runner_parser("magline.sitl.px4_run", __doc__, "--build",
                           "PX4's build folder of the px4_sitl_default target (holds bin/px4 and etc/)")
    parser.add_argument("--turned", type=float, default=90.0, help="the turned compass's yaw on the body (°)")
    args = parser.parse_args(argv)
    if not (args.build / "bin" / "px4").is_file() or not (args.build / "etc").is_dir():
        print(f"PX4 SITL not found in {args.build}: build PX4's px4_sitl_default target and give its build "
              "folder (it holds bin/px4 and etc/)", file=sys.stderr)
        return 2
    refused = in_private_network("magline.sitl.px4_run", argv)
    if refused:
        print(refused, file=sys.stderr)
        return 2
    workdir = args.workdir or Path(tempfile.mkdtemp(prefix="magline-sitl-px4-"))
    build = args.build.resolve()
    return summarise(f"PX4 SITL {args.build}", workdir,
                     {"good": lambda folder: one_unit(build, folder, args.seed, 0.0),
                      "turned": lambda folder: one_unit(build, folder, args.seed, args.turned),
                      "swept": lambda folder: swept_unit(build, folder, args.seed)}, args.json, args.unit)

if __name__ == "__main__":
    sys.exit(main())
