"""A turntable rig's cradle tilts: what the operator is asked for, what the accelerometer should then
read, the words and the picture, and which tilt shows the field the most directions not seen yet.

Frames: the unit's body is forward-right-down (the autopilots' FRD); the cradle turns it by ``pitch``
(nose up positive) then ``roll`` (right side down positive) on a table that turns about the vertical.
At rest the accelerometer reads the specific force ``g·(sin θ, −cos θ·sin φ, −cos θ·cos φ)``.

Why the choice by coverage: one revolution of the table shows the field a ring of directions in the
unit's axes, which the cradle's tilt places; the tilt whose ring crosses the most coverage bins not yet
hit is the one that brings the calibration closest to determined (the station's stop rule decides when).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from magline.core.fit.coverage import bin_index

if TYPE_CHECKING:
    from scipy.spatial.transform import Rotation

GRAVITY_MSS = 9.80665
RING_STEPS = 72  # directions per revolution when a tilt's ring is predicted (5° apart)


def _angle_words(value: float, plus: str, minus: str) -> str:
    return f"{plus if value > 0 else minus} {abs(value):g}°"


@dataclass(frozen=True)
class Tilt:
    """One setting of the cradle: ``pitch_deg`` nose up (+) or down (−), ``roll_deg`` right side down (+)
    or left side down (−), ``say``: the words the operator reads (made from the angles when empty)."""

    pitch_deg: float = 0.0
    roll_deg: float = 0.0
    say: str = ""

    @property
    def words(self) -> str:
        return self.say or tilt_words(self.pitch_deg, self.roll_deg)

    def rotation(self) -> Rotation:
        """Body → table: the cradle's pitch, then its roll (FRD, ZYX Euler with no yaw)."""
        from scipy.spatial.transform import Rotation  # on use: SciPy's import costs every command's start

        return Rotation.from_euler("ZYX", [0.0, self.pitch_deg, self.roll_deg], degrees=True)

    def gravity_body(self) -> NDArray:
        """The specific force the accelerometer reads at rest in this tilt (m/s², body axes)."""
        return self.rotation().inv().apply([0.0, 0.0, -GRAVITY_MSS])

    def picture(self) -> dict[str, float]:
        """What a drawing of the cradle needs: its side view turned by the pitch, its front view by the roll."""
        return {"pitch_deg": self.pitch_deg, "roll_deg": self.roll_deg}


def tilt_words(pitch_deg: float, roll_deg: float) -> str:
    """``level``, ``nose down 45°``, ``on its left side``, ``upside down``, ``nose up 45°, right side down 45°``."""
    parts = []
    pitch, roll = round(pitch_deg), round(((roll_deg + 180.0) % 360.0) - 180.0)
    if abs(pitch) >= 85:
        return "standing on its tail" if pitch > 0 else "standing on its nose"
    if pitch:
        parts.append(_angle_words(pitch, "nose up", "nose down"))
    if abs(roll) >= 175:
        parts.append("upside down")
    elif abs(roll) == 90:
        parts.append("on its right side" if roll > 0 else "on its left side")
    elif roll:
        parts.append(_angle_words(roll, "right side down", "left side down"))
    return ", ".join(parts) or "level"


def tilt_of_gravity(gravity_mss: NDArray) -> Tilt:
    """The tilt an accelerometer's reading at rest says the cradle is in (to 5°, words for the operator)."""
    f = np.asarray(gravity_mss, float) / max(float(np.linalg.norm(gravity_mss)), 1e-9)
    pitch = np.degrees(np.arcsin(np.clip(f[0], -1.0, 1.0)))
    roll = np.degrees(np.arctan2(-f[1], -f[2]))
    return Tilt(5.0 * round(pitch / 5.0), 5.0 * round(roll / 5.0))


def vector_angle_deg(a: NDArray, b: NDArray) -> float:
    """The angle between two vectors (degrees)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    cos = float(a @ b / max(np.linalg.norm(a) * np.linalg.norm(b), 1e-12))
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def off_by_deg(gravity_mss: NDArray, tilt: Tilt) -> float:
    """The angle between what the accelerometer reads and what ``tilt`` would make it read."""
    return vector_angle_deg(gravity_mss, tilt.gravity_body())


# What a station without named tilts chooses from: level, nose down and up, on each side, upside down and
# the 45° steps between (standing on the nose or tail needs no roll: the table's turn is then a roll).
COVERAGE_TILTS: tuple[Tilt, ...] = tuple(
    [Tilt(0.0, roll) for roll in (0.0, 90.0, -90.0, 180.0, 45.0, -45.0, 135.0, -135.0)]
    + [Tilt(pitch, roll) for pitch in (-45.0, 45.0) for roll in (0.0, 90.0, -90.0, 180.0)]
    + [Tilt(-90.0, 0.0), Tilt(90.0, 0.0)])


def ring_bins(tilt: Tilt, inclination_deg: float, sensor_to_body: NDArray, n_bins: int) -> set[int]:
    """The coverage bins one revolution of the table shows the field in, for a unit in ``tilt``: the
    field (dipping ``inclination_deg`` below the horizon) in the sensor's axes as the table turns."""
    incl = np.radians(inclination_deg)
    field = np.array([np.cos(incl), 0.0, np.sin(incl)])  # north and down, in the table's frame
    yaws = np.linspace(0.0, 360.0, RING_STEPS, endpoint=False)
    from scipy.spatial.transform import Rotation

    table = Rotation.from_euler("Z", yaws[:, None], degrees=True)
    body = tilt.rotation().inv().apply(table.inv().apply(field))  # the field in the unit's body at each yaw
    sensor = body @ np.asarray(sensor_to_body, float)  # v_sensor = Rᵀ·v_body, as rows
    return set(int(b) for b in bin_index(sensor, n_bins))


def best_tilt(candidates: list[Tilt] | tuple[Tilt, ...], covered: list[set[int]], inclination_deg: float,
              sensor_to_body: list[NDArray], n_bins: int) -> tuple[Tilt | None, int]:
    """The candidate whose revolution hits the most bins not covered yet, summed over the units on the
    cradle (each with its own sensor's mounting and coverage); (None, 0) when none adds one."""
    best, gain = None, 0
    for tilt in candidates:
        new = sum(len(ring_bins(tilt, inclination_deg, rotation, n_bins) - seen)
                  for seen, rotation in zip(covered, sensor_to_body, strict=True))
        if new > gain:
            best, gain = tilt, new
    return best, gain
