"""The firmwares' discrete sensor orientations as rotation matrices.

ArduPilot's ``COMPASS_ORIENTn`` / ``AHRS_ORIENTATION`` and PX4's ``CAL_MAGn_ROT`` /
``SENS_BOARD_ROT`` share MAVLink's ``MAV_SENSOR_ORIENTATION`` numbering (0 = none, 2 = Yaw90,
8 = Roll180, …).  The table is built from the enum's own descriptions in pymavlink's dialect
("Roll: 90, Pitch: 0, Yaw: 270"), so the numbers are the standard's, not a list typed here.

Convention (both firmwares' ``rotate()``): a value ``k`` maps a vector from the sensor's axes to the
body's, ``v_body = R_k · v_sensor`` with ``R_k = Rz(yaw)·Ry(pitch)·Rx(roll)``; a sensor *mounted*
as ``k`` (ArduPilot SITL's ``SIM_MAGn_ORIENT = k``) is corrected by the parameter value ``k``.
"""

from __future__ import annotations

import re

import numpy as np
from numpy.typing import NDArray
from pymavlink.dialects.v20 import common as _mavlink

CUSTOM = 100  # MAV_SENSOR_ROTATION_CUSTOM: PX4's custom Euler angles (CAL_MAGn_ROLL/PITCH/YAW)
_ANGLE = re.compile(r"(Roll|Pitch|Yaw):\s*(-?\d+)")


def _euler_matrix(roll: float, pitch: float, yaw: float) -> NDArray:
    r, p, y = np.deg2rad([roll, pitch, yaw])
    rx = np.array([[1, 0, 0], [0, np.cos(r), -np.sin(r)], [0, np.sin(r), np.cos(r)]])
    ry = np.array([[np.cos(p), 0, np.sin(p)], [0, 1, 0], [-np.sin(p), 0, np.cos(p)]])
    rz = np.array([[np.cos(y), -np.sin(y), 0], [np.sin(y), np.cos(y), 0], [0, 0, 1]])
    return rz @ ry @ rx


def _table() -> tuple[dict[int, NDArray], dict[int, str]]:
    matrices: dict[int, NDArray] = {}
    names: dict[int, str] = {}
    for value, entry in sorted(_mavlink.enums["MAV_SENSOR_ORIENTATION"].items()):
        angles = dict.fromkeys(("Roll", "Pitch", "Yaw"), 0.0)
        found = _ANGLE.findall(entry.description or "")
        if not found:
            continue  # CUSTOM and ENUM_END carry no angles
        for axis, degrees in found:
            angles[axis] = float(degrees)
        matrix = _euler_matrix(angles["Roll"], angles["Pitch"], angles["Yaw"])
        matrices[value] = np.where(np.abs(matrix) < 1e-12, 0.0, matrix)
        label = "".join(f"{axis}{int(angles[axis])}" for axis in ("Roll", "Pitch", "Yaw") if angles[axis])
        names[value] = label or "None"
    return matrices, names


ORIENTATIONS, _NAMES = _table()


def _right_angles() -> dict[int, NDArray]:
    """The 24 right-angle orientations, each under its lowest enum value (36 = Roll90Pitch180Yaw90 is
    the same rotation as 10 = Roll180Yaw90: the firmware's lower number is named)."""
    out: dict[int, NDArray] = {}
    for value, matrix in ORIENTATIONS.items():
        if not np.allclose(np.abs(matrix), np.round(np.abs(matrix)), atol=1e-9):
            continue
        if any(np.allclose(matrix, m, atol=1e-9) for m in out.values()):
            continue
        out[value] = matrix
    return out


RIGHT_ANGLE = _right_angles()


def orientation_matrix(value: int) -> NDArray:
    """R of ``v_body = R·v_sensor`` for an enum value; a value the table lacks is a clear error."""
    try:
        return ORIENTATIONS[int(value)]
    except KeyError:
        raise ValueError(f"orientation {value} is not a MAV_SENSOR_ORIENTATION value with known angles") from None


def orientation_name(value: int) -> str:
    """``Yaw90``, ``Roll180`` — the firmware's own words for a value; its ``None`` (0) as "no rotation",
    which read as a program's missing value in a sentence ("configured None (0)")."""
    if int(value) == 0:
        return "no rotation"
    return _NAMES.get(int(value), f"orientation {value}")


def rotation_angle_deg(a: NDArray, b: NDArray) -> float:
    """The angle of the rotation that takes ``b`` onto ``a`` (0 when equal)."""
    cos = (np.trace(np.asarray(a) @ np.asarray(b).T) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def nearest_right_angle(matrix: NDArray) -> tuple[int, float]:
    """The right-angle orientation closest to ``matrix`` and the angle left between them (degrees)."""
    best = min(RIGHT_ANGLE, key=lambda v: rotation_angle_deg(matrix, RIGHT_ANGLE[v]))
    return best, rotation_angle_deg(matrix, RIGHT_ANGLE[best])
