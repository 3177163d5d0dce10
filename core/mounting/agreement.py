"""Do two calibrated magnetometers give the unit the same heading?

Why at the station: both firmwares compare their compasses before arming (ArduPilot's "Compasses
inconsistent" allows tens of degrees), far too coarse to ship a unit whose GPS-mast compass and
board compass disagree by a few degrees — enough to make the estimator switch compasses in flight.
Here the heading is taken as the firmware will take it: each sensor's calibrated field in body axes,
projected onto the horizontal plane the accelerometer gives, the two paired by time.

The difference is taken as the mean over a sliding window (:data:`WINDOW_S`) around each reading, and
the median and the largest of those are judged: the heading an estimator uses is filtered over
seconds, and a single reading's noise (0.3 µT on a 22 µT horizontal field is 0.8°, so the median of
raw differences of two good sensors is 0.7°) says nothing about the mounting — a constant offset or
a stretch of attitudes where the sensors disagree does.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from magline.core.mounting.estimate import ImuSeries

WINDOW_S = 1.0


@dataclass
class HeadingAgreement:
    median_deg: float  # median |heading difference| over the tumble (each a 1 s window's mean)
    max_deg: float  # the largest of them
    mean_deg: float  # signed mean (a constant yaw offset between the sensors)
    pairs: int


def _interp_rows(t_new: NDArray, t: NDArray, values: NDArray) -> NDArray:
    order = np.argsort(t)
    return np.column_stack([np.interp(t_new, np.asarray(t)[order], np.asarray(values)[order, k]) for k in range(3)])


def heading_agreement(body_a: NDArray, t_a_ms: NDArray, body_b: NDArray, t_b_ms: NDArray,
                      imu: ImuSeries) -> HeadingAgreement | None:
    """Heading difference of sensor B against sensor A (body-axis calibrated fields on their own time
    stamps); None when the readings do not overlap in time."""
    t_a = np.asarray(t_a_ms, float)
    lo = max(np.min(t_b_ms), np.min(imu.t_ms))
    hi = min(np.max(t_b_ms), np.max(imu.t_ms))
    inside = (t_a >= lo) & (t_a <= hi)
    if inside.sum() < 10:
        return None
    t = t_a[inside]
    a = np.asarray(body_a, float)[inside]
    b = _interp_rows(t, t_b_ms, body_b)
    up = _interp_rows(t, imu.t_ms, imu.accel_mss)
    up = up / np.linalg.norm(up, axis=1, keepdims=True)
    ha = a - np.einsum("ij,ij->i", a, up)[:, None] * up
    hb = b - np.einsum("ij,ij->i", b, up)[:, None] * up
    diff = np.degrees(np.arctan2(np.einsum("ij,ij->i", up, np.cross(ha, hb)), np.einsum("ij,ij->i", ha, hb)))
    span_ms = WINDOW_S * 1000.0
    starts = np.searchsorted(t, t - span_ms / 2)
    ends = np.searchsorted(t, t + span_ms / 2)
    csum = np.concatenate([[0.0], np.cumsum(diff)])
    windowed = (csum[ends] - csum[starts]) / np.maximum(ends - starts, 1)
    return HeadingAgreement(median_deg=float(np.median(np.abs(windowed))), max_deg=float(np.max(np.abs(windowed))),
                            mean_deg=float(np.mean(diff)), pairs=len(diff))
