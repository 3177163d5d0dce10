"""PX4's calibration parameters: slot choice by device id, the fit → CAL_MAGn_* mapping.

Conventions (``docs/firmware.md``, *Conventions* and *PX4*): PX4 stores offsets in Gauss and *subtracts* them,
``m = S·(raw − OFF)`` in the sensor frame, so with magline's ``S·(m_raw − h)`` in µT:
OFF = h/100, SCALE = diag(S), XODIAG = S12, YODIAG = S13, ZODIAG = S23 (ODIAG from 1.12 only).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from magline.plugin import DutError, ParamValue

if TYPE_CHECKING:
    from magline.plugin import FitResult

SLOTS = 4
AXES = ("X", "Y", "Z")
UT_PER_GAUSS = 100.0
INT_SUFFIXES = ("_ID", "_PRIO", "_ROT")
INT_PARAMS = {"SENS_MAG_AUTOCAL", "MBE_ENABLE", "SENS_MAG_MODE", "SENS_MAG_SIDES", "SENS_BOARD_ROT", "CAL_MAG_COMP_TYP",
              "SYS_FAC_CAL_MODE"}
ROT_CUSTOM_EULER = 100
PRIO_EXTERNAL, PRIO_INTERNAL = 75, 50


def is_int_param(name: str) -> bool:
    return name in INT_PARAMS or name.endswith(INT_SUFFIXES)


def choose_slot(slot_ids: list[int], device_id: int, preferred: int) -> int:
    """PX4's own rule (FindAvailableCalibrationIndex): the slot already holding the id, else the
    preferred slot (the sensor's uORB instance) if free, else the first free one — never by position."""
    if device_id in slot_ids:
        return slot_ids.index(device_id)
    if 0 <= preferred < len(slot_ids) and slot_ids[preferred] == 0:
        return preferred
    if 0 in slot_ids:
        return slot_ids.index(0)
    raise DutError(f"no free CAL_MAG slot for magnetometer {device_id}: the slots hold "
                   f"{', '.join(map(str, slot_ids))} (clear stale slots: set their CAL_MAGn_ID to 0)")


def fit_to_params(fit: FitResult, slot: int, device_id: int, prio: int, with_odiag: bool) -> dict[str, ParamValue]:
    p = f"CAL_MAG{slot}_"
    s = np.asarray(fit.soft_iron)
    if not with_odiag:
        off = np.abs(s - np.diag(np.diag(s))).max()
        if off > 1e-9:
            raise DutError(f"this firmware has no CAL_MAGn_xODIAG; a full soft-iron fit (off-diagonal up to "
                           f"{off:.4f}) cannot be written — fit the diagonal model")
    params: dict[str, ParamValue] = {p + "ID": int(device_id), p + "PRIO": int(prio)}
    params |= {f"{p}{a}OFF": float(v) / UT_PER_GAUSS for a, v in zip(AXES, fit.hard_iron_ut, strict=True)}
    params |= {f"{p}{a}SCALE": float(v) for a, v in zip(AXES, np.diag(s), strict=True)}
    if with_odiag:
        params |= {p + "XODIAG": float(s[0, 1]), p + "YODIAG": float(s[0, 2]), p + "ZODIAG": float(s[1, 2])}
    return params


def rotation_params(rotation: NDArray, slot: int) -> dict[str, ParamValue]:
    """A coil-measured misalignment as PX4's custom rotation: ``m_body = R·S·(raw − OFF)`` with
    R = Rz(yaw)·Ry(pitch)·Rx(roll), degrees — exactly the polar factor of the affine fit."""
    from scipy.spatial.transform import Rotation  # on use: scipy.spatial costs every CLI start a third of a second

    yaw, pitch, roll = Rotation.from_matrix(np.asarray(rotation)).as_euler("ZYX", degrees=True)
    p = f"CAL_MAG{slot}_"
    return {p + "ROT": ROT_CUSTOM_EULER, p + "ROLL": float(roll), p + "PITCH": float(pitch), p + "YAW": float(yaw)}


def euler_rotation(roll: float, pitch: float, yaw: float) -> NDArray:
    """The rotation CAL_MAGn_ROLL/PITCH/YAW (degrees) hold: Rz(yaw)·Ry(pitch)·Rx(roll), sensor → body."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_euler("ZYX", [yaw, pitch, roll], degrees=True).as_matrix()
