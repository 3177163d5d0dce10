"""INAV's compass calibration in its own terms (``docs/firmware.md``, *INAV*).

INAV applies, per axis in the sensor's axes, ``out = (raw − magzero)·1024 / maggain`` (counts), then turns
the result by its alignment into its body axes, forward-left-up.  magline fits in forward-right-down axes
of the same sensor (INAV's flipped in y and z, :data:`INAV_TO_FRD` = ``F``), so its offset ``h`` is
INAV's with y and z negated and its diagonal soft iron is INAV's own.  INAV's own calibration makes the
field 1024 counts long (each gain the largest deviation from the offset on its axis), the size its attitude
estimator weights the compass by.  magline's fit puts ``S·(m − h)`` on a sphere of ``B`` µT with ``S``
diagonal (INAV holds no off-diagonal term), so with ``c`` counts per µT: ``magzero = c·F·h``,
``maggain = c·B / S_ii``, and INAV's output is ``1024·F·S·(m − h) / B`` — back in µT, in magline's
body axes, as ``F·out · B / 1024``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from magline.plugin import (
    INAV_ALIGNMENT_NAMES,
    INAV_ALIGNMENTS,
    INAV_COMPASS_DEFAULT_ALIGNMENT,
    INAV_TO_FRD,
    DutError,
    inav_rotation_in_frd,
    orientation_matrix,
)

if TYPE_CHECKING:
    from magline.plugin import FitResult

OFFSETS = ("magzero_x", "magzero_y", "magzero_z")
GAINS = ("maggain_x", "maggain_y", "maggain_z")
UNITY_GAIN = 1024  # the gain of an uncalibrated axis, and the length INAV's calibration gives the field
NEUTRAL: dict[str, int] = {**dict.fromkeys(OFFSETS, 0), **dict.fromkeys(GAINS, UNITY_GAIN)}
INT16 = (-32768, 32767)
MAX_ORIENTATION = 101  # MAV_SENSOR_ORIENTATION values are below this
FLIP = np.array(INAV_TO_FRD, float)  # INAV's axes to magline's and back (its own inverse)


def fit_to_settings(fit: FitResult, counts_per_ut: float) -> dict[str, int]:
    """The settings that make INAV's output ``1024·S·(m − h)/B``; a fit INAV cannot hold is a
    :class:`DutError` saying why (an off-diagonal term, a value outside int16)."""
    s = np.asarray(fit.soft_iron, float)
    off = float(np.abs(s - np.diag(np.diag(s))).max())
    if off > 1e-9:
        raise DutError(f"INAV holds no off-diagonal soft iron (the fit has up to {off:.4f}): fit the diagonal model")
    diag = np.diag(s)
    if np.any(diag <= 0):
        raise DutError(f"the fit's soft iron has a non-positive diagonal {diag.round(4).tolist()}: no INAV gain is it")
    zero = np.round(FLIP @ np.asarray(fit.hard_iron_ut, float) * counts_per_ut).astype(int)
    gain = np.round(counts_per_ut * float(fit.field_ut) / diag).astype(int)
    settings = dict(zip(OFFSETS, map(int, zero), strict=True)) | dict(zip(GAINS, map(int, gain), strict=True))
    wide = {k: v for k, v in settings.items() if not INT16[0] <= v <= INT16[1] or (k in GAINS and v == 0)}
    if wide:
        raise DutError(f"INAV holds int16 offsets and non-zero gains; the calibration needs "
                       f"{', '.join(f'{k} = {v}' for k, v in wide.items())}: not written")
    return settings


def output_to_ut(counts: NDArray, field_ut: float) -> NDArray:
    """INAV's calibrated output (counts in its body axes, radius 1024 in the field it was calibrated in) in
    µT, in magline's body axes (forward-right-down)."""
    return (np.asarray(counts, float) @ FLIP) * field_ut / UNITY_GAIN


def alignment_matrix(value: int) -> NDArray:
    """``v_body = R·v_sensor`` for an ``align_mag`` value (DEFAULT is CW270FLIP for the compass), in
    magline's axes: INAV's turn, :func:`inav_rotation_in_frd` (CW90 is Yaw90)."""
    return inav_rotation_in_frd(INAV_ALIGNMENTS[int(value) or INAV_COMPASS_DEFAULT_ALIGNMENT])


def alignment_name(value: int) -> str:
    return INAV_ALIGNMENT_NAMES[int(value)] if 0 <= int(value) < len(INAV_ALIGNMENT_NAMES) else str(value)


def _orientations() -> dict[int, NDArray]:
    known = {}
    for value in range(MAX_ORIENTATION):
        try:
            known[value] = orientation_matrix(value)
        except ValueError:
            continue
    return known


def mav_orientation(matrix: NDArray) -> int:
    """The MAV_SENSOR_ORIENTATION value nearest a rotation (exactly it for INAV's eight alignments): what
    the mounting check speaks."""
    return min(_orientations().items(), key=lambda item: -float(np.trace(item[1] @ np.asarray(matrix).T)))[0]


def alignment_for(orientation: int) -> int | None:
    """The ``align_mag`` value that holds MAV orientation ``orientation``; None when none of INAV's eight does."""
    wanted = orientation_matrix(orientation)
    return next((v for v in INAV_ALIGNMENTS if np.allclose(alignment_matrix(v), wanted)), None)
