"""Where a magnetometer's axes point in the body, from gravity and the calibrated field.

Why this works: whatever the unit's attitude, the angle between gravity and the Earth field is the
same (90° plus the field's inclination).  The accelerometer gives gravity in body axes; the
calibrated magnetometer gives the field in its own axes.  Only the right rotation between the two
frames makes that angle constant over a tumble — a compass rotated by 90° about Z still traces a
perfect sphere, but its angle to gravity then swings by tens of degrees.  With attitudes spread over
the sphere the rotation is fully determined (no rotation other than the identity keeps
``gᵀ·R·E·Rᵀ·f`` constant for every attitude ``R``), and the constant itself is the inclination.

Method: every right-angle orientation is tried as a start (the firmwares' discrete mountings), the
best is refined by nonlinear least squares (scipy, robust loss against readings taken while the
unit accelerated) over a rotation vector and the inclination.  The readings are paired by time: the
accelerometer is interpolated to each magnetometer reading's time stamp, never taken from the message
that happened to carry the reading (reference §16: pairing as sent biased a mounting by 1.8°).  A
delay between the two clocks is *not* fitted: at a steady turning rate a delay is exactly a fixed
turn of the sensor, so a fitted lag would swallow the very misalignment being measured — backends
stamp each reading with the time it was taken.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from magline.core.mounting.orientations import RIGHT_ANGLE, nearest_right_angle

STILL_TOLERANCE = 0.08  # |a| within 8 % of gravity: readings taken while the unit accelerated are left out
MIN_PAIRS = 30
ROBUST_SCALE = 0.01  # soft-L1 scale of the cosine residual (about 0.6° near 90°)
MAX_SIGMA_DEG = 3.0  # a mounting known worse than this is not proven (too few distinct attitudes)


class MountingUnobservable(ValueError):
    """The readings cannot determine the mounting (no accelerometer, too few still readings, attitudes
    too alike).  The station could not judge the unit: an ERROR, never a FAIL."""


@dataclass
class ImuSeries:
    """The unit's inertial readings in body axes (forward-right-down), on the magnetometers' clock.

    ``accel_mss``: specific force in m/s² (at rest it points up: ``[0, 0, −9.81]`` level);
    ``gyro_rads``: angular rate where the stream has it.
    """

    t_ms: NDArray
    accel_mss: NDArray
    gyro_rads: NDArray | None = None

    def __len__(self) -> int:
        return len(self.t_ms)


@dataclass
class MountingEstimate:
    """``data_to_body``: the rotation with ``v_body = R · v_data`` for the sensor's calibrated readings."""

    data_to_body: NDArray
    sigma_deg: float  # 1σ of the rotation's largest uncertain axis
    inclination_deg: float  # the field's inclination as the unit saw it (positive down)
    inclination_sigma_deg: float
    angle_rms_deg: float  # RMS spread of the gravity-to-field angle after the fit
    pairs: int  # magnetometer readings paired with a still accelerometer reading

    @property
    def right_angle(self) -> tuple[int, float]:
        """The discrete orientation nearest to the estimate and the angle left to it (degrees)."""
        return nearest_right_angle(self.data_to_body)

    @staticmethod
    def right_angle_of(matrix: NDArray) -> tuple[int, float]:
        return nearest_right_angle(matrix)

    def to_dict(self) -> dict:
        value, residual = self.right_angle
        return {"data_to_body": np.round(self.data_to_body, 6).tolist(), "sigma_deg": self.sigma_deg,
                "inclination_deg": self.inclination_deg, "inclination_sigma_deg": self.inclination_sigma_deg,
                "angle_rms_deg": self.angle_rms_deg, "pairs": self.pairs,
                "nearest_orientation": value, "from_nearest_deg": residual}


def _unit(v: NDArray) -> NDArray:
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _sorted_imu(imu: ImuSeries) -> tuple[NDArray, NDArray]:
    t = np.asarray(imu.t_ms, float)
    order = np.argsort(t)
    return t[order], np.asarray(imu.accel_mss, float)[order]


def _still_inside(t_mag: NDArray, t: NDArray, acc: NDArray, imu: ImuSeries) -> NDArray:
    """The magnetometer readings with an accelerometer reading around them that sees gravity alone."""
    when = np.asarray(t_mag, float)
    inside = (when >= t[0]) & (when <= t[-1])
    a = np.column_stack([np.interp(when, t, acc[:, k]) for k in range(3)])
    g = np.median(np.linalg.norm(acc, axis=1))
    still = inside & (np.abs(np.linalg.norm(a, axis=1) - g) < STILL_TOLERANCE * g)
    if imu.gyro_rads is not None and len(imu.gyro_rads) == len(t):
        rate = np.linalg.norm(np.asarray(imu.gyro_rads, float)[np.argsort(np.asarray(imu.t_ms, float))], axis=1)
        still &= np.interp(when, t, rate) < np.radians(120.0)
    return still


def _paired(mag: NDArray, t_mag: NDArray, imu: ImuSeries) -> tuple[NDArray, NDArray]:
    """Unit field and unit specific-force vectors at the same instants (still readings only)."""
    t, acc = _sorted_imu(imu)
    keep = _still_inside(t_mag, t, acc, imu)
    when = np.asarray(t_mag, float)[keep]
    a = np.column_stack([np.interp(when, t, acc[:, k]) for k in range(3)])
    return _unit(np.asarray(mag, float)[keep]), _unit(a)


def _spread(m: NDArray, a: NDArray, r: NDArray) -> float:
    return float(np.std(np.einsum("ij,ij->i", a, m @ r.T)))


def residual_variance(resid: NDArray, params: int) -> float:
    """The variance of one residual as the covariance ``s² · (JᵀJ)⁻¹`` needs it, from residuals in
    time order.

    Why not their mean square: one reading far off (taken before the unit moved, a glitch) is all
    but ignored by the soft-L1 fit, yet its square alone inflated the σ twentyfold, so a tumble read
    on to its count for a mounting long determined.  The scale is the residuals' median absolute
    deviation (a normal's σ).  Why the correlation factor: the hand's accelerations tilt "gravity"
    for half a second at a time, so neighbouring residuals are alike and the readings are worth fewer
    independent ones; taken as independent the σ was a third too small (13 % of synthetic units beyond
    3σ).  The factor is ``1 + 2·Σρₖ`` over the residuals' autocorrelations up to the first that is not
    positive (the usual effective-sample-size correction), computed on the readings within 4 of the
    robust scale."""
    resid = np.asarray(resid, float)
    dof = max(len(resid) - params, 1)
    scale = 1.4826 * float(np.median(np.abs(resid - np.median(resid))))
    if scale == 0.0:
        return float(np.sum(resid**2) / dof)
    inliers = resid[np.abs(resid - np.median(resid)) <= 4.0 * scale]
    centred = inliers - inliers.mean()
    denom = float(centred @ centred)
    factor = 1.0
    for lag in range(1, len(centred) // 4):
        rho = float(centred[:-lag] @ centred[lag:]) / denom if denom > 0.0 else 0.0
        if rho <= 0.0:
            break
        factor += 2.0 * rho
    return scale**2 * len(resid) / dof * factor


def estimate_mounting(mag_cal: NDArray, t_mag_ms: NDArray, imu: ImuSeries | None) -> MountingEstimate:
    """The rotation from the calibrated magnetometer's axes (``mag_cal``, rows, any unit) to the body,
    with the field's inclination; raises :class:`MountingUnobservable` with the reason when the
    readings cannot prove it."""
    from scipy.optimize import least_squares  # on use: scipy costs every command start
    from scipy.spatial.transform import Rotation

    if imu is None or len(imu) < 2:
        raise MountingUnobservable("the unit's stream carries no accelerometer readings")
    if not np.any(np.linalg.norm(np.asarray(imu.accel_mss, float), axis=1) > 1.0):
        raise MountingUnobservable("the accelerometer fields of the stream are all zero")
    if t_mag_ms is None or len(t_mag_ms) != len(mag_cal):
        raise MountingUnobservable("the magnetometer readings carry no time stamps to pair them with gravity")

    m, a = _paired(mag_cal, t_mag_ms, imu)
    if len(m) < MIN_PAIRS:
        raise MountingUnobservable(f"only {len(m)} magnetometer readings were taken while the unit was still "
                                   f"enough to see gravity ({MIN_PAIRS} needed)")
    start = min(RIGHT_ANGLE.values(), key=lambda r: _spread(m, a, r))

    def residuals(p: NDArray) -> NDArray:
        r = Rotation.from_rotvec(p[:3]).as_matrix() @ start
        return np.einsum("ij,ij->i", a, m @ r.T) + np.sin(p[3])

    incl0 = -np.arcsin(np.clip(np.mean(np.einsum("ij,ij->i", a, m @ start.T)), -1, 1))
    fit = least_squares(residuals, np.array([0.0, 0.0, 0.0, incl0]), loss="soft_l1", f_scale=ROBUST_SCALE)
    rotation = Rotation.from_rotvec(fit.x[:3]).as_matrix() @ start
    inclination = float(fit.x[3])
    try:
        cov = residual_variance(fit.fun, len(fit.x)) * np.linalg.inv(fit.jac.T @ fit.jac)
    except np.linalg.LinAlgError:
        raise MountingUnobservable("the attitudes seen do not determine the mounting") from None
    sigma_rot = float(np.degrees(np.sqrt(max(np.linalg.eigvalsh(cov[:3, :3]).max(), 0.0))))
    sigma_incl = float(np.degrees(np.sqrt(max(cov[3, 3], 0.0))))
    if not np.isfinite(sigma_rot) or sigma_rot > MAX_SIGMA_DEG:
        raise MountingUnobservable(f"the attitudes seen determine the mounting only to ±{sigma_rot:.1f}° "
                                   f"(1σ; ±{MAX_SIGMA_DEG:g}° needed): tumble through more orientations")
    angles = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", a, m @ rotation.T), -1, 1)))
    return MountingEstimate(data_to_body=rotation, sigma_deg=sigma_rot, inclination_deg=float(np.degrees(inclination)),
                            inclination_sigma_deg=sigma_incl,
                            angle_rms_deg=float(np.sqrt(np.mean((angles - np.mean(angles)) ** 2))),
                            pairs=len(m))
