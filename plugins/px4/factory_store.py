"""PX4's factory calibration store (``/fs/mtd_caldata``), written and proven by a station
(``docs/firmware.md``, *Factory calibration storage*).

The route, and why it: the store is written only by the commander's own calibrations
(``FactoryCalibrationStorage`` in ``src/modules/commander``), which with ``SYS_FAC_CAL_MODE`` = 1 export
every ``CAL_*`` parameter (not ``CAL_MAG_SIDES`` nor ``*_PRIO``) and every ``TC_*`` — the station's
``CAL_MAGn_*`` among them, as written and saved just before.  Of those calibrations the gyro's is the
one a station can run unattended: it needs the unit still for a few seconds, where the accelerometer's
needs six poses and the magnetometer's a tumble that would overwrite the station's own values.  MAVLink
FTP cannot write the store on NuttX (``_validatePathIsWritable`` allows the board's root path only).
The gyro's offsets are calibrated again as a side effect (the unit rests on the fixture: what a
factory gyro calibration is).  The commander reports in STATUSTEXT (``calibration_messages.h``), after a
ground station's heartbeat has arrived — MAVSDK sends one.
"""

from __future__ import annotations

import queue
import re
import time
from typing import TYPE_CHECKING

import numpy as np

from magline.plugin import DutError, ParamValue, get_listening
from magline.plugins.px4.calibration import is_int_param

if TYPE_CHECKING:
    from magline.plugins.px4.link import Px4Link

FACTORY_STORE = "/fs/mtd_caldata"
MODE_PARAM = "SYS_FAC_CAL_MODE"
MODE_ALL_SENSORS = 1
MAV_CMD_PREFLIGHT_CALIBRATION, MAV_CMD_PREFLIGHT_STORAGE = 241, 245
GYRO = 1.0  # MAV_CMD_PREFLIGHT_CALIBRATION param1: the gyro
RESET_CALIBRATION = 3  # MAV_CMD_PREFLIGHT_STORAGE param1: ParamResetSensorFactory (CAL_ACC/GYRO/MAG*, save, reboot)
DONE, FAILED, CANCELLED = "[cal] calibration done:", "[cal] calibration failed", "[cal] calibration cancelled"
PRINTED_HALF_UNIT = 0.5e-6 + 1e-12  # bsondump's %.6f
BSON_LINE = re.compile(r"BSON_(INT32|DOUBLE):\s*(\S+)\s*=\s*(\S+)")


def held_by_store(name: str) -> bool:
    """Whether the store holds ``name`` (``filter_calibration_params`` with SYS_FAC_CAL_MODE = 1)."""
    return (name.startswith("CAL_") and name != "CAL_MAG_SIDES" and not name.endswith("_PRIO")) \
        or name.startswith("TC_")


def copy_into_store(link: Px4Link, mode_after: int, timeout_s: float) -> str:
    """Set SYS_FAC_CAL_MODE = 1, run the gyro calibration and wait for its verdict; whatever happens,
    SYS_FAC_CAL_MODE is then set to ``mode_after`` and saved.  Returns the firmware's words; a refusal or
    a failure is a :class:`DutError` quoting them ("ERROR: Motion during calibration", "ERROR: cannot open
    calibration storage")."""
    link.set(MODE_PARAM, MODE_ALL_SENSORS, is_int_param(MODE_PARAM))
    inbox, handle = link.subscribe("STATUSTEXT")
    try:
        _start_gyro_calibration(link)
        return _verdict(inbox, timeout_s)
    finally:
        link.unsubscribe(handle)
        link.set(MODE_PARAM, mode_after, is_int_param(MODE_PARAM))
        # the commander holds autosave while it exports: a value set after it ends is saved by asking
        link.require_accepted_by_worker(MAV_CMD_PREFLIGHT_STORAGE, "forced parameter save", 1)


def _start_gyro_calibration(link: Px4Link) -> None:
    link.require_accepted_by_worker(MAV_CMD_PREFLIGHT_CALIBRATION,
                                    "the gyro calibration that writes the factory store", GYRO)


def _verdict(inbox: queue.Queue, timeout_s: float) -> str:
    said: list[str] = []
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            text = str(get_listening(inbox, max(deadline - time.monotonic(), 0.0)).get("text", "")).strip()
        except queue.Empty:
            raise DutError(f"the gyro calibration that writes the factory store gave no verdict within {timeout_s:g} s"
                           + (f" (it said: {'; '.join(said)})" if said else "")) from None
        if not text:
            continue
        said.append(text)
        if text.startswith(DONE):
            return text
        if text.startswith((FAILED, CANCELLED)):
            told = [t for t in said if not t.startswith(("[cal] calibration started", "[cal] progress"))]
            raise DutError("PX4's gyro calibration, which writes the factory store, failed: " + "; ".join(told))


def store_contents(shell_output: str, written: dict[str, ParamValue]) -> dict[str, ParamValue | None]:
    """What ``bsondump /fs/mtd_caldata`` printed, for each written parameter the store should hold.
    ``bsondump`` prints a float with six decimals (``%.6f``) of the float32 it holds: a value within that
    rounding of the written one, as a float32, is the written one."""
    held: dict[str, ParamValue] = {}
    for kind, name, value in BSON_LINE.findall(shell_output):
        held[name] = int(value) if kind == "INT32" else float(value)
    out: dict[str, ParamValue | None] = {}
    for name, value in written.items():
        if not held_by_store(name):
            continue
        shown = held.get(name)
        if isinstance(shown, float) and abs(shown - float(np.float32(value))) <= PRINTED_HALF_UNIT:
            shown = value
        out[name] = shown
    return out


def reset_calibration(link: Px4Link) -> None:
    """PREFLIGHT_STORAGE param1 = 3: the commander resets CAL_ACC*, CAL_GYRO*, CAL_MAG*, saves and reboots —
    the parameters then come back from the store alone."""
    link.require_accepted_by_worker(MAV_CMD_PREFLIGHT_STORAGE, "the calibration reset that proves the factory store",
                          RESET_CALIBRATION)


def read_named(link: Px4Link, names: list[str]) -> dict[str, ParamValue]:
    return {name: link.get(name, is_int_param(name)) for name in names if held_by_store(name)}
