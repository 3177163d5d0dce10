"""Good ArduCopter units, and one whose mast compass is turned, through the real ``magline run`` on
ArduPilot's own SITL.

ArduCopter's SITL is its own truth-keeper: each simulated compass is distorted by the simulator's
parameters (``SIM_MAGn_OFS`` in mG, ``SIM_MAGn_DIA``/``ODI``, ``SIM_MAGn_ORIENT``; ``AP_Compass_SITL``
reads ``M_sim⁻¹·B − OFS_sim``), and the ``calibration`` model turns the vehicle itself through its
18-pose cycle once ``SERVO5_FUNCTION = 0`` and ``MAV_CMD_DO_SET_SERVO(5, 1250)``.  A right calibration
then writes ``COMPASS_OFSn = SIM_MAGn_OFS`` (the firmware adds its offset) and ``COMPASS_DIAn/ODIn =
SIM_MAGn_DIA/ODI``.  The field is the firmware's own table (``AP_Declination/tables.cpp``) at SITL's home,
put on a grid point of the table so that no interpolation stands between the truth and the firmware.

The station is the shipped ``stations/ardupilot-sim.yaml`` pointed at the SITL; its power cycle is the
firmware's own reboot (ArduPilot's SITL re-executes itself).  After the run the process is killed (a hard
power cut) and started again on the same storage (``eeprom.bin``), and every compass's parameters are
read back and held to the truth.  The SITL runs in a private network namespace: it listens on every
interface.

A third unit is calibrated and swept for its current interference in one run: the calibration model draws
no current, so SITL runs its FlightAxis back end, fed by :mod:`magline.sitl.ardupilot_flightaxis` (the same
kind of tumble, and the battery current of a simulated electronic load that the station drives as on a line).
``SIM_MAG_MOT`` (mG per amp, body frame, before each compass's own distortion) is the truth: a right
compensation writes ``COMPASS_MOTCT = 2`` and ``COMPASS_MOTn = −SIM_MAG_MOT`` for every compass.

    python -m magline.sitl.ardupilot_run --source PATH/TO/ardupilot [--workdir DIR] [--seed 1] [--json OUT]

``--source`` is the tree ArduCopter's SITL was built in (``./waf configure --board sitl``, ``./waf
copter``): its ``build/sitl/bin/arducopter`` and its declination table.  Prints one line per check and exits
0 when every one holds.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from pymavlink import mavutil

from magline.sim.load import LoadSim
from magline.sitl.ardupilot_flightaxis import FlightAxisPeer, Tumble
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

SERIAL0 = "tcp:127.0.0.1:5760"  # SITL's SERIAL0: the station's link (SITL waits for it at boot)
HOME = (50.0, 10.0, 100.0, 0.0)  # latitude, longitude (a grid point of the declination table), altitude m, heading
COMPASSES = 3  # ArduCopter's SITL starts with three compasses
# SITL's own dataflash log, kept in the unit's folder (logs/*.BIN) whether the vehicle is armed or not: its SIM
# messages are the simulator's attitude at each SITL instant (25 Hz with the fast-attitude bit), the truth the
# compass and IMU (MAG, IMU at the loop's rate) are made from — what the station's readings are held to when
# one of them is in question (docs/firmware.md). Bits: fast and medium attitude, IMU, compass, fast IMU.
DATAFLASH_LOG = {"LOG_DISARMED": 1.0, "LOG_BITMASK": float(1 << 0 | 1 << 1 | 1 << 7 | 1 << 13 | 1 << 18)}
ORIENT_YAW90 = 2
UT_PER_GAUSS = 100.0


@dataclass
class ApTruth:
    """Each compass's distortion as the SITL's parameters hold it (mG; ``raw = M⁻¹·B − OFS``), the
    orientation each really sits at against the one the firmware expects, and the site's field."""

    offsets_mg: list[list[float]]
    diagonals: list[list[float]]
    off_diagonals: list[list[float]]
    turned: dict[int, int] = field(default_factory=dict)  # compass index (0-based) → SIM_MAGn_ORIENT
    field_ut: float = 0.0
    inclination_deg: float = 0.0
    mag_mot_mg_per_a: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])  # SIM_MAG_MOT
    noise_mg: float = 0.0  # SIM_MAG_RND: each axis of each sample uniform within ±this (SITL's compass has none)

    @classmethod
    def drawn(cls, seed: int, **changes) -> ApTruth:
        """Plausible compasses: offsets up to ±300 mG, a diagonal within ±5 %, off-diagonals within ±0.03."""
        rng = np.random.default_rng(seed)
        return cls(offsets_mg=rng.uniform(-300, 300, (COMPASSES, 3)).round(1).tolist(),
                   diagonals=np.exp(rng.uniform(-0.05, 0.05, (COMPASSES, 3))).round(4).tolist(),
                   off_diagonals=rng.uniform(-0.03, 0.03, (COMPASSES, 3)).round(4).tolist(), **changes)

    def sim_params(self) -> dict[str, float]:
        params: dict[str, float] = {}
        for n in range(COMPASSES):
            for a, axis in enumerate("XYZ"):
                params[f"SIM_MAG{n + 1}_OFS_{axis}"] = self.offsets_mg[n][a]
                params[f"SIM_MAG{n + 1}_DIA_{axis}"] = self.diagonals[n][a]
                params[f"SIM_MAG{n + 1}_ODI_{axis}"] = self.off_diagonals[n][a]
            params[f"SIM_MAG{n + 1}_ORIENT"] = float(self.turned.get(n, 0))
        for a, axis in enumerate("XYZ"):
            params[f"SIM_MAG_MOT_{axis}"] = self.mag_mot_mg_per_a[a]
        params["SIM_MAG_RND"] = self.noise_mg
        return params

    def expected_compensation(self) -> dict[str, float]:
        """The COMPASS_MOT* a right current compensation writes: minus the field per amp, every compass."""
        out = {"COMPASS_MOTCT": 2.0}
        for n in range(COMPASSES):
            suffix = "" if n == 0 else str(n + 1)
            for a, axis in enumerate("XYZ"):
                out[f"COMPASS_MOT{suffix}_{axis}"] = -self.mag_mot_mg_per_a[a]
        return out

    def expected(self) -> dict[str, float]:
        """The COMPASS_* a right calibration writes."""
        out: dict[str, float] = {}
        for n in range(COMPASSES):
            suffix = "" if n == 0 else str(n + 1)
            for a, axis in enumerate("XYZ"):
                out[f"COMPASS_OFS{suffix}_{axis}"] = self.offsets_mg[n][a]
                out[f"COMPASS_DIA{suffix}_{axis}"] = self.diagonals[n][a]
                out[f"COMPASS_ODI{suffix}_{axis}"] = self.off_diagonals[n][a]
        return out


def table_field(source: Path, latitude: float, longitude: float) -> tuple[float, float]:
    """The field (µT) and its inclination (°) ArduPilot's SITL makes at a grid point of its own table."""
    text = (source / "libraries" / "AP_Declination" / "tables.cpp").read_text()

    def at(name: str) -> float:
        body = re.search(rf"{name}\[LAT_TABLE_SIZE\]\[LON_TABLE_SIZE\]\s*=\s*\{{(.*?)\}};", text, re.S)
        if body is None:
            raise SystemExit(f"no {name} in {source}/libraries/AP_Declination/tables.cpp")
        rows = [[float(v) for v in re.findall(r"-?\d+\.\d+", row)] for row in re.findall(r"\{([^{}]*)\}", body[1])]
        return rows[round((latitude + 90) / 10)][round((longitude + 180) / 10)]

    return at("intensity_table") * UT_PER_GAUSS, at("inclination_table")


class ApSitl:
    """ArduCopter's SITL process on a working directory (its ``eeprom.bin``), started and killed as a
    power supply would; the runner stays its parent (SITL exits when its parent does)."""

    def __init__(self, binary: Path, workdir: Path, model: str = "calibration") -> None:
        self.binary, self.workdir, self.model, self.proc = binary, workdir, model, None
        self.log = open(workdir / "sitl.log", "ab")  # noqa: SIM115 — kept open across power cycles

    def start(self) -> None:
        home = ",".join(f"{v:g}" for v in HOME)
        self.proc = subprocess.Popen([str(self.binary), "--model", self.model, "--home", home, "-I0"],
                                     cwd=self.workdir, stdout=self.log, stderr=subprocess.STDOUT,
                                     stdin=subprocess.DEVNULL)

    def cut(self) -> None:
        if self.proc is not None:
            died = self.proc.poll()
            if died is not None:
                self.log.write(f"[magline] the SITL had ended by itself: exit status {died}\n".encode())
                self.log.flush()
            self.proc.kill()
            self.proc.wait()


def _link(timeout_s: float = 60.0) -> mavutil.mavfile:
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            link = mavutil.mavlink_connection(SERIAL0, source_system=245, source_component=190, retries=0)
            if link.wait_heartbeat(timeout=10) is not None:
                return link
            link.close()
        except OSError:
            pass
        if time.monotonic() > deadline:
            raise RuntimeError(f"ArduCopter's SITL did not answer on {SERIAL0} within {timeout_s:g} s")
        time.sleep(0.5)


def _set(link: mavutil.mavfile, params: dict[str, float]) -> None:
    for name, value in params.items():
        for _ in range(5):
            link.mav.param_set_send(link.target_system, link.target_component, name.encode(), value,
                                    mavutil.mavlink.MAV_PARAM_TYPE_REAL32)
            echo = link.recv_match(type="PARAM_VALUE", blocking=True, timeout=2.0,
                                   condition=f"PARAM_VALUE.param_id == '{name}'")
            if echo is not None:
                break
        else:
            raise RuntimeError(f"ArduCopter's SITL did not take {name} = {value}")


def start_tumbling(link: mavutil.mavfile) -> None:
    """The calibration model's automatic 18-pose cycle."""
    _set(link, {"SERVO5_FUNCTION": 0.0})
    link.mav.command_long_send(link.target_system, link.target_component, mavutil.mavlink.MAV_CMD_DO_SET_SERVO, 0,
                               5, 1250, 0, 0, 0, 0, 0)
    ack = link.recv_match(type="COMMAND_ACK", blocking=True, timeout=5.0,
                          condition=f"COMMAND_ACK.command == {mavutil.mavlink.MAV_CMD_DO_SET_SERVO}")
    if ack is None or ack.result != 0:
        raise RuntimeError(f"ArduCopter's SITL refused DO_SET_SERVO(5, 1250): {ack}")


def _fresh(workdir: Path) -> None:
    """A new board: no storage, no results from an earlier run in this folder."""
    workdir.mkdir(parents=True, exist_ok=True)
    for stale in ("eeprom.bin", "results.sqlite"):
        (workdir / stale).unlink(missing_ok=True)


def _run_and_keep(sitl: ApSitl, truth: ApTruth, station: Path, serial: str, names: list[str],
                  tumbling: bool) -> tuple[dict, float, dict[str, float]]:
    """One unit on SITL: its truth set, ``magline run`` of ``station``, a hard power cut, and ``names`` read
    back from what the board kept (with every compass's id).  ``tumbling``: the calibration model turns
    the vehicle through its own cycle (the FlightAxis peer turns it otherwise)."""
    workdir = sitl.workdir
    try:
        sitl.start()
        link = _link()
        _set(link, {**truth.sim_params(), **DATAFLASH_LOG})
        if tumbling:
            start_tumbling(link)
        link.close()
        record, cycle_s = run_station(station, serial, workdir)
        sitl.cut()  # the hard power cut: what was saved is what the unit keeps
        sitl.start()
        link = _link()
        ids = [f"COMPASS_DEV_ID{'' if n == 0 else n + 1}" for n in range(COMPASSES)]
        kept = read_params(link, [*names, *ids])
        link.close()
    finally:
        sitl.cut()
        sitl.log.close()
    return record, cycle_s, kept


def _write_truth(workdir: Path, truth: ApTruth, **more: object) -> None:
    (workdir / "truth.json").write_text(json.dumps({**asdict(truth), "expected": truth.expected(), **more},
                                                   indent=2) + "\n")


def one_unit(source: Path, workdir: Path, seed: int, turned: dict[int, int]) -> tuple[dict, list[Check]]:
    _fresh(workdir)
    field_ut, inclination = table_field(source, HOME[0], HOME[1])
    truth = ApTruth.drawn(seed, turned=turned, field_ut=field_ut, inclination_deg=inclination)
    _write_truth(workdir, truth)
    station = write_station("ardupilot-sim.yaml", workdir, truth.field_ut, truth.inclination_deg,
                            {"connection": SERIAL0})
    sitl = ApSitl(source / "build" / "sitl" / "bin" / "arducopter", workdir)
    record, cycle_s, kept = _run_and_keep(sitl, truth, station, f"SITL-AP-{seed}", [*truth.expected()],
                                          tumbling=True)
    return record, _judge(truth, record, kept, cycle_s)


PER_AMP_GOAL_MG, PER_AMP_GOAL_SHARE = 0.5, 0.03  # the tier's goal for a written compensation: 0.5 mG/A + 3 %
SWEPT_NOISE_MG = 3.0  # SIM_MAG_RND of the swept unit: σ 1.7 mG (0.17 µT) per axis, a common compass's


def swept_unit(source: Path, workdir: Path, seed: int) -> tuple[dict, list[Check]]:
    """A good unit whose compasses follow the battery current: calibrated, swept, compensated and proven by
    the station in one run on SITL's FlightAxis back end, the current drawn by a simulated electronic load."""
    _fresh(workdir)
    field_ut, inclination = table_field(source, HOME[0], HOME[1])
    per_amp = np.random.default_rng(seed + 1000).uniform(-1.5, 1.5, 3).round(2).tolist()  # ≤ 22 % at 40 A
    # a compass's noise, as a real one has: SITL's noiseless compass sends one value in every message while the
    # unit is held for the sweep, and the station (which drops a stream's repeats) has no readings to sweep with
    truth = ApTruth.drawn(seed, field_ut=field_ut, inclination_deg=inclination, mag_mot_mg_per_a=per_amp,
                          noise_mg=SWEPT_NOISE_MG)
    _write_truth(workdir, truth, expected_compensation=truth.expected_compensation())
    load = LoadSim("tcp:127.0.0.1:0").start()
    peer = FlightAxisPeer(Tumble(), load.sinking_current, lambda: load.input_on).start()
    try:
        station = write_station("interference-sim.yaml", workdir, truth.field_ut, truth.inclination_deg,
                                {"connection": SERIAL0},
                                {"current_source": {"type": "electronic-load",
                                                    "options": {"resource": load.visa_resource,
                                                                "max_current_a": 60.0}}})
        sitl = ApSitl(source / "build" / "sitl" / "bin" / "arducopter", workdir, model="flightaxis")
        record, cycle_s, kept = _run_and_keep(sitl, truth, station, f"SITL-AP-MOT-{seed}",
                                              [*truth.expected(), *truth.expected_compensation()], tumbling=False)
    finally:
        peer.stop()
        load.stop()
    return record, [*_judge(truth, record, kept, cycle_s), *_compensation_checks(truth, kept)]


def _compensation_checks(truth: ApTruth, kept: dict[str, float]) -> list[Check]:
    """The current compensation kept after the power cut, against minus ``SIM_MAG_MOT``."""
    expected = truth.expected_compensation()
    checks = [Check("COMPASS_MOTCT after a power cut", f"{kept['COMPASS_MOTCT']:g}", "2 (current)",
                    kept["COMPASS_MOTCT"] == expected["COMPASS_MOTCT"])]
    for n in range(COMPASSES):
        suffix = "" if n == 0 else str(n + 1)
        names = [f"COMPASS_MOT{suffix}_{a}" for a in "XYZ"]
        want = np.array([expected[k] for k in names])
        error = float(np.linalg.norm(np.array([kept[k] for k in names]) - want))
        allowed = PER_AMP_GOAL_MG + PER_AMP_GOAL_SHARE * float(np.linalg.norm(want))
        checks.append(Check(f"COMPASS_MOT{suffix} after a power cut", f"|Δ| {error:.3f} mG/A",
                            f"≤ {allowed:.3f} mG/A (0.5 + 3 %)", error <= allowed))
    return checks


def _judge(truth: ApTruth, record: dict, kept: dict[str, float], cycle_s: float) -> list[Check]:
    verdict, cause = record.get("verdict"), record.get("cause") or ""
    if truth.turned:
        (index, orient), = truth.turned.items()
        fix = f"COMPASS_ORIENT{'' if index == 0 else index + 1} = {orient}"
        written = (record.get("params") or {}).get("written") or {}
        return [Check("turned compass FAILs naming its fix", f"{verdict}: {cause[:60]}", f"FAIL, '{fix}'",
                      verdict == "fail" and fix in cause),
                Check("nothing written to a failed unit", f"{len(written)} written", "none", not written)]
    checks = [Check("good unit PASSes", f"{verdict} {cause[:40]}", "pass", verdict == "pass")]
    expected = truth.expected()
    for n in range(COMPASSES):
        suffix = "" if n == 0 else str(n + 1)
        offs = [f"COMPASS_OFS{suffix}_{a}" for a in "XYZ"]
        matrix = [f"COMPASS_DIA{suffix}_{a}" for a in "XYZ"] + [f"COMPASS_ODI{suffix}_{a}" for a in "XYZ"]
        checks += calibration_checks(
            record, int(kept[f"COMPASS_DEV_ID{suffix}"]),
            (np.array([kept[k] for k in offs]), np.array([expected[k] for k in offs])),
            (np.array([kept[k] for k in matrix]), np.array([expected[k] for k in matrix])),
            (f"COMPASS_OFS{suffix}", f"COMPASS_DIA{suffix}/ODI{suffix}"))
    return [*checks, *station_figures(record, cycle_s)]


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = runner_parser("magline.sitl.ardupilot_run", __doc__, "--source",
                           "the ArduPilot tree ArduCopter's SITL was built in (holds build/sitl/bin/arducopter)")
    args = parser.parse_args(argv)
    if not (args.source / "build" / "sitl" / "bin" / "arducopter").is_file():
        print(f"ArduCopter SITL not found in {args.source}: build it there (./waf configure --board sitl; "
              "./waf copter) and give the tree", file=sys.stderr)
        return 2
    refused = in_private_network("magline.sitl.ardupilot_run", argv)  # SITL listens on every interface
    if refused:
        print(refused, file=sys.stderr)
        return 2
    workdir = args.workdir or Path(tempfile.mkdtemp(prefix="magline-sitl-ardupilot-"))
    source = args.source.resolve()
    return summarise(f"ArduCopter SITL {args.source}", workdir,
                     {"good": lambda folder: one_unit(source, folder, args.seed, {}),
                      "turned": lambda folder: one_unit(source, folder, args.seed, {1: ORIENT_YAW90}),
                      "swept": lambda folder: swept_unit(source, folder, args.seed)}, args.json, args.unit)


if __name__ == "__main__":
    sys.exit(main())
