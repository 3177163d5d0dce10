"""PX4's factory calibration store, checked on PX4's own SITL: the station's route writes it, and a board
that loads it before the user's parameters gets the station's calibration back after a reset.

What it runs: the real ``magline run`` of a good unit with ``persist: factory-storage`` (the station
writes ``CAL_MAG0_*``, sets ``SYS_FAC_CAL_MODE = 1`` and has the commander run a gyro calibration, which
exports every ``CAL_*`` to ``/fs/mtd_caldata``); then the calibration a customer's reset would take away
(``MAV_CMD_PREFLIGHT_STORAGE`` 3: every ``CAL_ACC/GYRO/MAG*`` reset and saved), the power cut, and what
the board holds after it boots.

What it changes, and why: a posix PX4 uses ``/fs/mtd_caldata`` as a path of the host and its startup
script never loads it (``ROMFS/px4fmu_common/init.d-posix/rcS``), where a NuttX board with the partition
does, before the user's file (``init.d/rcS``: ``param load /fs/mtd_caldata``, then ``param import``).  The
check runs PX4 on a copy of the build's ``etc`` whose ``rcS`` has that one line, at the same place (before
``param select``); ``--stock`` runs the startup as built, where the reset calibration does not come back.
Nothing of the host is touched: the run is in private mount and network namespaces with a fresh tmpfs on
``/fs``.

    python scripts/px4_factory_store_check.py --build PATH/TO/build/px4_sitl_default [--workdir DIR] [--stock]

Prints one line per check and exits 0 when every one holds.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import struct
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

from pymavlink import mavutil

from magline.sitl.checks import Check, last_record
from magline.sitl.px4_hil import HilFeeder, Px4Truth
from magline.sitl.px4_power import Px4Process
from magline.sitl.px4_run import PARAM_LINK, read_px4_params, station_file

PRIVATE = "MAGLINE_FACTORY_CHECK_NS"
STORE = Path("/fs/mtd_caldata")  # the path PX4's FactoryCalibrationStorage opens, a host path on posix
LOAD_FACTORY = "if [ -f /fs/mtd_caldata ]; then param load /fs/mtd_caldata; fi  # as init.d/rcS on a board\n"
RESET_SENSOR_CALIBRATION = 3  # MAV_CMD_PREFLIGHT_STORAGE param1: ParamResetSensorFactory (CAL_ACC/GYRO/MAG*, saved)
AXES = ("XOFF", "YOFF", "ZOFF", "XSCALE", "YSCALE", "ZSCALE", "XODIAG", "YODIAG", "ZODIAG")
SAME = 1e-6  # the store holds what was written (floats through BSON doubles)


def private_namespaces(argv: list[str]) -> str | None:
    """Re-execute in private mount and network namespaces with a fresh tmpfs on ``/fs``; returns only inside
    them (or a reason it cannot)."""
    if os.environ.get(PRIVATE) != "1":
        if shutil.which("unshare") is None:
            return "unshare (util-linux) is needed: the check runs in private mount and network namespaces"
        os.execvpe("unshare", ["unshare", "-mn", "--propagation", "private", sys.executable, *argv],
                   {**os.environ, PRIVATE: "1"})
    subprocess.run(["ip", "link", "set", "lo", "up"], check=True)
    Path("/fs").mkdir(exist_ok=True)
    subprocess.run(["mount", "-t", "tmpfs", "tmpfs", "/fs"], check=True)
    return None


def startup_with_factory_load(build: Path, workdir: Path) -> Path:
    """A copy of the build's ``etc`` whose startup loads the factory store before the user's parameters."""
    etc = workdir / "etc"
    shutil.rmtree(etc, ignore_errors=True)
    shutil.copytree(build / "etc", etc, symlinks=True)
    rcs = etc / "init.d-posix" / "rcS"
    text = rcs.read_text()
    anchor = "param select $PARAM_FILE\n"
    if anchor not in text:
        raise SystemExit(f"{rcs} has no '{anchor.strip()}' line: this PX4's startup differs from the one checked")
    rcs.write_text(text.replace(anchor, LOAD_FACTORY + anchor, 1))
    return etc


def bson_doubles_and_ints(path: Path) -> dict[str, float]:
    """The top-level int32 and double elements of PX4's BSON parameter file (``lib/parameters/tinybson``)."""
    data = path.read_bytes()
    if len(data) < 5:
        return {}
    size = struct.unpack_from("<i", data)[0]
    values, at = {}, 4
    while at < min(size, len(data)) - 1:
        kind = data[at]
        end = data.index(b"\0", at + 1)
        name = data[at + 1:end].decode()
        at = end + 1
        if kind == 0x01:
            values[name] = struct.unpack_from("<d", data, at)[0]
            at += 8
        elif kind == 0x10:
            values[name] = float(struct.unpack_from("<i", data, at)[0])
            at += 4
        else:
            raise ValueError(f"{path}: BSON element type {kind:#x} at {name!r}, which PX4's parameter files do not use")
    return values


def run_with_operator(station: Path, serial: str, workdir: Path, feeder: HilFeeder) -> dict:
    """``magline run`` of one unit, the unit set down as soon as the station says its tumble is done (the
    factory store's gyro calibration wants it still); the record as ``magline show`` gives it."""
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    with open(workdir / "run.log", "w") as log:
        proc = subprocess.Popen([sys.executable, "-m", "magline.core.cli", "run", str(station), "--serial", serial],
                                cwd=workdir, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env,
                                stdin=subprocess.DEVNULL)
        for line in proc.stdout:
            log.write(line)
            if "acquire PASS" in line:
                feeder.rest()
        proc.wait()
    return last_record(station, workdir)


def reset_sensor_calibration(timeout_s: float = 30.0) -> str:
    """What a customer's "reset calibration" does: every CAL_ACC/GYRO/MAG* back to its default, saved."""
    link = mavutil.mavlink_connection(PARAM_LINK, source_system=245, source_component=190)
    try:
        if link.wait_heartbeat(timeout=timeout_s) is None:
            raise RuntimeError("PX4 sent no heartbeat")
        link.mav.command_long_send(link.target_system, 1, mavutil.mavlink.MAV_CMD_PREFLIGHT_STORAGE, 0,
                                   RESET_SENSOR_CALIBRATION, 0, 0, 0, 0, 0, 0)
        ack = link.recv_match(type="COMMAND_ACK", blocking=True, timeout=timeout_s,
                              condition=f"COMMAND_ACK.command == {mavutil.mavlink.MAV_CMD_PREFLIGHT_STORAGE}")
        return "no answer" if ack is None else mavutil.mavlink.enums["MAV_RESULT"][ack.result].name
    finally:
        link.close()


def calibration(kept: dict[str, float]) -> dict[str, float]:
    return {f"CAL_MAG0_{a}": kept[f"CAL_MAG0_{a}"] for a in AXES}


def largest_difference(a: dict[str, float], b: dict[str, float]) -> float:
    return max(abs(float(a[k]) - float(b.get(k, float("nan")))) if k in b else float("inf") for k in a)


def check(build: Path, workdir: Path, seed: int, stock: bool) -> list[Check]:
    board = workdir / "board"
    board.mkdir(parents=True, exist_ok=True)
    STORE.write_bytes(b"")  # the partition, empty: FactoryCalibrationStorage's open() checks that it exists
    etc = build / "etc" if stock else startup_with_factory_load(build, workdir)
    truth = Px4Truth.drawn(seed)
    (workdir / "truth.json").write_text(json.dumps(truth.expected, indent=2) + "\n")
    feeder = HilFeeder(truth, seed=seed)
    threading.Thread(target=feeder.serve, daemon=True).start()
    px4 = Px4Process.prepare(build, board, etc=etc)
    checks = []
    try:
        px4.on()
        station = station_file(board, truth, {"persist": "factory-storage"})
        record = run_with_operator(station, f"SITL-PX4-FACTORY-{seed}", board, feeder)
        store_words = (record.get("persistence") or {}).get("store", "")
        checks.append(Check("unit PASSes with persist: factory-storage", f"{record.get('verdict')} "
                            f"{(record.get('cause') or '')[:40]}", "pass", record.get("verdict") == "pass"))
        checks.append(Check("the record says the store was written", store_words[:60], "'factory … store, written'",
                            store_words.startswith("factory calibration store, written")))
        written = {k: v for k, v in ((record.get("params") or {}).get("written") or {}).items()
                   if k.startswith("CAL_MAG0_") and k[9:] in AXES}
        stored = bson_doubles_and_ints(STORE)
        held = largest_difference(written, stored) if written else float("inf")
        checks.append(Check(f"{STORE} holds CAL_MAG0_* written", f"{len(stored)} parameters, max |Δ| {held:.2g}",
                            f"≤ {SAME:g}", held <= SAME))
        px4.off()
        px4.on()
        said = reset_sensor_calibration()
        after_reset = calibration(read_px4_params([f"CAL_MAG0_{a}" for a in AXES]))
        checks.append(Check("a calibration reset takes it away", f"{said}, XOFF {after_reset['CAL_MAG0_XOFF']:+.5f}",
                            "ACCEPTED, XOFF 0", said == "MAV_RESULT_ACCEPTED" and after_reset["CAL_MAG0_XOFF"] == 0.0))
        px4.off()  # the board's reboot after a reset
        px4.on()
        back = calibration(read_px4_params([f"CAL_MAG0_{a}" for a in AXES]))
        gap = largest_difference(written, back) if written else float("inf")
        if stock:
            checks.append(Check("as built, the store is not loaded at boot", f"XOFF {back['CAL_MAG0_XOFF']:+.5f}",
                                "XOFF 0 (the calibration gone)", back["CAL_MAG0_XOFF"] == 0.0))
        else:
            checks.append(Check("loaded before the user's file, it comes back", f"max |Δ| {gap:.2g}",
                                f"≤ {SAME:g} of what was written", gap <= SAME))
    finally:
        px4.off()
        feeder.stop()
    return checks


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--build", type=Path, required=True,
                        help="PX4's build folder of the px4_sitl_default target (holds bin/px4 and etc/)")
    parser.add_argument("--workdir", type=Path, help="where the board's files stay (default: a temporary folder)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--stock", action="store_true", help="PX4's startup as built (it does not load the store)")
    args = parser.parse_args(argv)
    if not (args.build / "bin" / "px4").is_file():
        print(f"PX4 SITL not found in {args.build}: give the px4_sitl_default build folder", file=sys.stderr)
        return 2
    refused = private_namespaces([str(Path(__file__).resolve()), *argv])
    if refused:
        print(refused, file=sys.stderr)
        return 2
    workdir = (args.workdir or Path(tempfile.mkdtemp(prefix="magline-px4-factory-"))).resolve()
    checks = check(args.build.resolve(), workdir, args.seed, args.stock)
    print(f"PX4 factory calibration store, {'startup as built' if args.stock else 'store loaded before the user file'}"
          f" — files in {workdir}")
    print("\n".join(c.line() for c in checks))
    return 0 if all(c.holds for c in checks) else 1


if __name__ == "__main__":
    sys.exit(main())
