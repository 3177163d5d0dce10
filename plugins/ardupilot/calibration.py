"""ArduPilot's calibration parameters: names per compass set, the fit → parameter mapping, the
firmware's own limits, and the inverse of the correction it applies to streamed data.

Conventions (``docs/firmware.md``, *Conventions* and *ArduPilot*): ArduPilot works in milligauss, in the rotated body
frame, and *adds* its offsets: ``v = M·(SCALE·(raw + OFS))``.  magline's fit is
``m_cal = S·(m_raw − h)`` in µT, so OFS = −10·h, DIA = diag(S), ODI = (S12, S13, S23), SCALE = 1.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from magline.plugin import DutError

if TYPE_CHECKING:
    from magline.plugin import FitResult

SETS = ("", "2", "3")  # parameter suffix of compass set 1, 2, 3
AXES = ("X", "Y", "Z")
MG_PER_UT = 10.0
MAX_SCALE_FACTOR = 1.5  # COMPASS_SCALE outside [1/1.5, 1.5] is not applied
DIAG_LIMITS = (0.2, 5.0)  # CompassCalibrator fit_acceptable
OFFDIAG_LIMIT = 1.0


def set_names(suffix: str) -> dict[str, list[str]]:
    return {"OFS": [f"COMPASS_OFS{suffix}_{a}" for a in AXES], "DIA": [f"COMPASS_DIA{suffix}_{a}" for a in AXES],
            "ODI": [f"COMPASS_ODI{suffix}_{a}" for a in AXES], "SCALE": [f"COMPASS_SCALE{suffix}"],
            "DEV_ID": [f"COMPASS_DEV_ID{suffix}"], "ORIENT": [f"COMPASS_ORIENT{suffix}"],
            "EXTERN": ["COMPASS_EXTERNAL" if suffix == "" else f"COMPASS_EXTERN{suffix}"],
            "MOT": [f"COMPASS_MOT{suffix}_{a}" for a in AXES]}


def rename_for_set(name: str, old: str, new: str) -> str:
    """The same parameter of another set (whole sets move when priorities reorder them at boot)."""
    old_names = [n for names in set_names(old).values() for n in names]
    new_names = [n for names in set_names(new).values() for n in names]
    return new_names[old_names.index(name)] if name in old_names else name


def fit_to_params(fit: FitResult, suffix: str) -> dict[str, float]:
    """OFS = −10·h (mG, added by the firmware), DIA/ODI = S, SCALE = 1 (EKF3 needs a valid scale)."""
    names = set_names(suffix)
    s = np.asarray(fit.soft_iron)
    ofs = -MG_PER_UT * np.asarray(fit.hard_iron_ut)
    params = dict(zip(names["OFS"], map(float, ofs), strict=True))
    params |= dict(zip(names["DIA"], map(float, np.diag(s)), strict=True))
    params |= dict(zip(names["ODI"], map(float, (s[0, 1], s[0, 2], s[1, 2])), strict=True))
    params[names["SCALE"][0]] = 1.0
    return params


def check_firmware_limits(params: dict[str, float], suffix: str, offs_max_mg: float) -> None:
    """Refuse values ArduPilot itself would reject or flag, naming the limit (nothing is written)."""
    names = set_names(suffix)
    problems = []
    ofs = np.array([params[n] for n in names["OFS"]])
    if np.linalg.norm(ofs) > offs_max_mg:
        problems.append(f"offset |COMPASS_OFS{suffix}| = {np.linalg.norm(ofs):.0f} mG exceeds "
                        f"COMPASS_OFFS_MAX = {offs_max_mg:.0f} mG")
    for n in names["DIA"]:
        if not DIAG_LIMITS[0] < params[n] < DIAG_LIMITS[1]:
            problems.append(f"{n} = {params[n]:.4f} outside ArduPilot's diagonal limits "
                            f"{DIAG_LIMITS[0]}–{DIAG_LIMITS[1]}")
    for n in names["ODI"]:
        if abs(params[n]) >= OFFDIAG_LIMIT:
            problems.append(f"{n} = {params[n]:.4f} outside ArduPilot's off-diagonal limit ±{OFFDIAG_LIMIT}")
    if problems:
        raise DutError("calibration not written: " + "; ".join(problems))


@dataclass(frozen=True)
class HeldCalibration:
    """The calibration the firmware applies to a set's streamed field, so it can be undone.

    Why invert rather than neutralise: ArduPilot writes every PARAM_SET straight to storage, so
    neutralising the calibration before acquisition would change the unit permanently before it
    has passed anything; a run that stops early (link lost, operator abort, failed fit) would leave
    the unit uncalibrated.  Inverting touches nothing.  The inverse follows the firmware's rules
    exactly: SCALE only when inside [1/1.5, 1.5], the matrix only when some DIA is non-zero.
    Motor compensation (COMPASS_MOT·throttle or current) is not inverted: on the bench the unit is
    disarmed with zero throttle and no motor current.
    """

    ofs_mg: NDArray
    dia: NDArray
    odi: NDArray
    scale: float

    @classmethod
    def from_params(cls, values: dict[str, float], suffix: str) -> HeldCalibration:
        names = set_names(suffix)
        return cls(ofs_mg=np.array([values[n] for n in names["OFS"]]), dia=np.array([values[n] for n in names["DIA"]]),
                   odi=np.array([values[n] for n in names["ODI"]]), scale=float(values[names["SCALE"][0]]))

    def matrix(self) -> NDArray:
        m = np.eye(3)
        if np.any(self.dia != 0):
            d, o = self.dia, self.odi
            m = np.array([[d[0], o[0], o[1]], [o[0], d[1], o[2]], [o[1], o[2], d[2]]])
        if 1.0 / MAX_SCALE_FACTOR <= self.scale <= MAX_SCALE_FACTOR:
            m = m * self.scale
        return m

    def raw_ut(self, corrected_mg: NDArray) -> NDArray:
        """Raw body-frame field (µT) from what RAW_IMU / SCALED_IMU2/3 carried (mG, rows)."""
        m = self.matrix()
        if abs(np.linalg.det(m)) < 1e-6:
            raise DutError("the calibration the unit holds is singular; its raw data cannot be recovered "
                           "(reset COMPASS_DIA/ODI to identity)")
        raw_mg = np.linalg.solve(m, np.atleast_2d(corrected_mg).T).T - self.ofs_mg
        return raw_mg / MG_PER_UT
