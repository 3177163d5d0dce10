"""Where a magnetometer's axes point in the body, from gravity and the calibrated field.

Why this works: whatever the unit's attitude, the angle between gravity and the Earth field is the
same (90° plus the field's inclination).  The accelerometer gives gravity in body axes; the
calibrated magnetometer gives the field in its own axes.  Only the right rotation between the two
frames makes that angle constant over a tumble — a compass rotated by 90° about Z still traces a
perfect sphere, but its angle to gravity then swings by tens of degrees.  With attitudes spread over
the sphere the rotation is fully determined (no rotation other than the identity keeps
``gᵀ·R·E·Rᵀ·f`` constant for every attitude ``R``), and the constant itself is the inclination.

Method: the magnetometer's time skew against the accelerometer is found first
(:mod:`magline.core.mounting.skew`: neither firmware stamps a reading with the instant it was taken,
and a skew at 60°/s is a degree of apparent misalignment); every right-angle orientation is tried as a
start at that skew (the firmwares' discrete mountings), and the best is refined by nonlinear least
squares (scipy, robust loss against readings taken while the unit accelerated) over a rotation vector,
the inclination and the skew together, so the mounting's σ includes what the skew leaves uncertain.
A skew is not a turned sensor only while the unit turns about more than one axis: where the tumble
cannot tell them apart the σ says so and the mounting is not proven.

Why the skew's information is taken from the gravity's turn over a window, not from the fit's own
Jacobian: on a two-axis fixture turning at constant rates (outer axis vertical) a skew ``δ`` is
*exactly* a turn of the sensor by ``ω_inner·δ`` about the inner axis — the gravity–field angle cannot
tell them apart — yet the fit's Jacobian took the accelerometer's noise, differentiated, for
information, stated ±0.06° and was 12° off (the skew landing wherever the noise was least).  The
gravity's rate of turn from a central difference over a window as long as the motion allows (the
gravity turning half a radian, at most ±150 ms) carries the motion and far less of the noise, so such
a tumble's σ says what it leaves open.  Where the firmware's skew is known (:class:`SkewPrior`: the
station file's value, or the line's good units), it closes that direction: the skew and the mounting
are moved together along what the tumble leaves open, to where the prior puts the skew, and the σ is
the posterior's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from magline.core.mounting.orientations import RIGHT_ANGLE, nearest_right_angle
from magline.core.mounting.skew import (
    MIN_PAIRS,
    SKEW_SEARCH_MS,
    SKEW_STEP_MS,
    GravityTrack,
    coarse_skew_ms,
    unit_rows,
)

ROBUST_SCALE = 0.01  # soft-L1 scale of the cosine residual (about 0.6° near 90°)
MAX_SIGMA_DEG = 3.0  # a mounting known worse than this is not proven (too few distinct attitudes)
# The window the gravity's turn is differenced over for the skew's information: half of it as long as
# the gravity turns by TURN_WINDOW_RAD (the difference keeps sin(x)/x of the turn: 96 % at 0.5 rad), at
# most TURN_WINDOW_MAX_MS (the noise of a difference falls as the window grows) and at least
# TURN_WINDOW_PERIODS of the accelerometer's periods.
TURN_WINDOW_RAD = 0.5
TURN_WINDOW_MAX_MS = 150.0
TURN_WINDOW_PERIODS = 1.5
SKEW_EVIDENCE = 3.0  # how many standard errors the skew's own information must stand out by (_information)
SKEW_DOMINATES = 2.0  # an undetermined skew may at most double the mounting's σ before the mounting is a guess


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

    def gravity_track(self) -> GravityTrack:
        """The accelerometer at any instant (built once per series: every sensor of a unit, and the
        heading agreement, pair with the same one)."""
        track = self.__dict__.get("_track")
        if track is None:
            track = self.__dict__["_track"] = GravityTrack.of(self.t_ms, self.accel_mss, self.gyro_rads)
        return track


@dataclass(frozen=True)
class SkewPrior:
    """What is known of a sensor's time skew before the unit is tumbled: the firmware's message pipeline
    makes it (PX4's ``sensor_mag`` older than the IMU time it travels with, ArduCopter's compass later
    than its message), so a line knows it from the station file or from its own good units.  ``sigma_ms``
    is what one more unit's skew may be off it (the units' own spread, not the mean's error)."""

    skew_ms: float
    sigma_ms: float
    source: str  # in words: "the station file", "24 passing units of PART on station ID"

    def describe(self) -> str:
        return f"{self.skew_ms:.1f} ± {self.sigma_ms:.1f} ms ({self.source})"


@dataclass
class MountingEstimate:
    """``data_to_body``: the rotation with ``v_body = R · v_data`` for the sensor's calibrated readings."""

    data_to_body: NDArray
    sigma_deg: float  # 1σ of the rotation's largest uncertain axis
    inclination_deg: float  # the field's inclination as the unit saw it (positive down)
    inclination_sigma_deg: float
    angle_rms_deg: float  # RMS spread of the gravity-to-field angle after the fit
    pairs: int  # magnetometer readings paired with a still accelerometer reading
    skew_ms: float = 0.0  # the reading belongs this much after its stamp, on the accelerometer's clock
    skew_sigma_ms: float = 0.0
    # what the tumble alone says of the skew (∞ σ: nothing), and the prior it was joined with (None: none)
    own_skew_ms: float = 0.0
    own_skew_sigma_ms: float = 0.0
    prior: SkewPrior | None = None

    @property
    def skew_disagreement(self) -> float:
        """How many σ the unit's own skew lies off the prior (0 without one, or where the tumble says
        nothing of the skew): beyond 3 the unit is not timed as the line's units are."""
        if self.prior is None or not np.isfinite(self.own_skew_sigma_ms):
            return 0.0
        return abs(self.own_skew_ms - self.prior.skew_ms) / float(np.hypot(self.own_skew_sigma_ms,
                                                                            self.prior.sigma_ms))

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
                "skew_ms": round(self.skew_ms, 2), "skew_sigma_ms": round(self.skew_sigma_ms, 2),
                "own_skew_ms": round(self.own_skew_ms, 2),
                "own_skew_sigma_ms": round(self.own_skew_sigma_ms, 2) if np.isfinite(self.own_skew_sigma_ms)
                else None,
                "skew_prior": None if self.prior is None else {"skew_ms": self.prior.skew_ms,
                                                               "sigma_ms": self.prior.sigma_ms,
                                                               "source": self.prior.source},
                "nearest_orientation": value, "from_nearest_deg": residual}


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


# The mirrored mounting fits alike when its residuals are within this factor (plus a floor) of the fit's.
MIRROR_TIE, MIRROR_FLOOR = 3.0, 0.01


def mirrored(gravity_rows: NDArray, rotation: NDArray) -> NDArray:
    """``rotation`` turned 180° about the body axis gravity was seen least along.  Why: gravity seen in
    one plane only — a turntable's cradle tilted about one axis (level, on its sides, upside down) — gives
    ``gᵀ·R'·m = −gᵀ·R·m`` for every reading, so this mounting with the opposite inclination fits exactly
    as well: the readings cannot tell a sensor mounted Roll180 in a field pointing down from one mounted
    straight in a field pointing up."""
    from scipy.spatial.transform import Rotation

    axis = np.linalg.svd(gravity_rows, full_matrices=False)[2][-1]
    return Rotation.from_rotvec(np.pi * axis).as_matrix() @ rotation


def estimate_mounting(mag_cal: NDArray, t_mag_ms: NDArray, imu: ImuSeries | None, *,
                      skew_hint_ms: float | None = None, dip_deg: float | None = None,
                      skew_prior: SkewPrior | None = None) -> MountingEstimate:
    """The rotation from the calibrated magnetometer's axes (``mag_cal``, rows, any unit) to the body,
    with the field's inclination; raises :class:`MountingUnobservable` with the reason when the
    readings cannot prove it.  ``skew_hint_ms``: a skew found on the same stream before (a tumble's
    earlier snapshot), where the refinement starts instead of the coarse search.  ``dip_deg``: the local
    field's inclination (the field source's), which decides between a mounting and its mirror when
    gravity was seen in one plane only (:func:`mirrored`); without it that tumble cannot prove one.
    ``skew_prior``: what the line knows of this sensor's skew, joined with what the tumble says."""
    from scipy.optimize import least_squares  # on use: scipy costs every command start
    from scipy.spatial.transform import Rotation

    if imu is None or len(imu) < 2:
        raise MountingUnobservable("the unit's stream carries no accelerometer readings")
    if not np.any(np.linalg.norm(np.asarray(imu.accel_mss, float), axis=1) > 1.0):
        raise MountingUnobservable("the accelerometer fields of the stream are all zero")
    if t_mag_ms is None or len(t_mag_ms) != len(mag_cal):
        raise MountingUnobservable("the magnetometer readings carry no time stamps to pair them with gravity")

    track = imu.gravity_track()
    readings = unit_rows(np.asarray(mag_cal, float))
    stamps = np.asarray(t_mag_ms, float)
    reach = reading_span_ms(stamps)
    coarse = coarse_skew_ms(readings, stamps, track, reach) if skew_hint_ms is None else float(skew_hint_ms)
    accel, usable = track.at(stamps + (coarse or 0.0), reach)
    if coarse is None or usable.sum() < MIN_PAIRS:
        raise MountingUnobservable(f"only {int(usable.sum())} magnetometer readings were taken while the unit was "
                                   f"still enough to see gravity ({MIN_PAIRS} needed)")
    m, t = readings[usable], stamps[usable]
    start = min(RIGHT_ANGLE.values(), key=lambda r: _spread(m, unit_rows(accel[usable]), r))

    def gravity(skew: float) -> NDArray:
        return unit_rows(track.accel_at(t + skew))

    def residuals(p: NDArray) -> NDArray:
        r = Rotation.from_rotvec(p[:3]).as_matrix() @ start
        return np.einsum("ij,ij->i", gravity(p[4]), m @ r.T) + np.sin(p[3])

    incl0 = -np.arcsin(np.clip(np.mean(np.einsum("ij,ij->i", gravity(coarse), m @ start.T)), -1, 1))
    reach = SKEW_SEARCH_MS + SKEW_STEP_MS
    fit = least_squares(residuals, np.array([0.0, 0.0, 0.0, incl0, coarse]), loss="soft_l1", f_scale=ROBUST_SCALE,
                        x_scale=np.array([0.01, 0.01, 0.01, 0.01, 1.0]),
                        bounds=([-np.inf] * 4 + [-reach], [np.inf] * 4 + [reach]))
    rotation = Rotation.from_rotvec(fit.x[:3]).as_matrix() @ start
    # the residuals hold the inclination through its sine: I and 180° − I fit alike, and a turntable's few
    # tilts once let the solver wander to 118° for a 62° field (a good unit FAILed at 56° "error"); the
    # field's dip is in [−90°, 90°], the same sine there
    inclination, skew = float(np.arcsin(np.clip(np.sin(fit.x[3]), -1.0, 1.0))), float(fit.x[4])
    seen = gravity(skew)
    mirror = mirrored(seen, rotation)
    other = np.einsum("ij,ij->i", seen, m @ mirror.T) - np.sin(inclination)
    if np.sqrt(np.mean(other**2)) <= MIRROR_TIE * np.sqrt(np.mean(fit.fun**2)) + MIRROR_FLOOR:
        if dip_deg is None:
            raise MountingUnobservable("gravity was seen about one axis only: the mounting and the same turned "
                                       "180° fit alike, with the field pointing up or down — tilt the unit about "
                                       "its other axis too")
        if np.sign(inclination) != np.sign(dip_deg):  # the mirror is the one whose field dips as the place's
            rotation, inclination = mirror, -inclination
    variance = residual_variance(fit.fun, len(fit.x))
    information, determined = _information(track, m, t, rotation, inclination, skew, fit.fun, reach)
    information = information / variance
    if not determined:  # the skew anywhere in the search, as far as the tumble knows (a uniform's σ)
        information[4, 4] += 3.0 / reach**2
    own = _covariance(information)
    own_skew, own_sigma = skew, float(np.sqrt(own[4, 4])) if np.isfinite(own[4, 4]) else float("inf")
    cov = own
    if skew_prior is not None:
        rotation, inclination, skew, cov = _joined(skew_prior, information, rotation, inclination, skew,
                                                   lambda r, incl, sk: _polished(m, gravity(sk), r, incl))
    held = _covariance(information[:4, :4])  # the skew taken as known
    sigma_rot = _largest_sigma_deg(cov[:3, :3])
    sigma_incl = float(np.degrees(np.sqrt(max(cov[3, 3], 0.0)))) if np.isfinite(cov[3, 3]) else float("inf")
    # a skew the tumble does not determine, no prior, and most of the mounting's σ is what that skew could
    # move it by: a mounting judged so is a guess at the skew (a two-axis gimbal's 4.5° on good units)
    guessed = skew_prior is None and not determined and sigma_rot > SKEW_DOMINATES * _largest_sigma_deg(held[:3, :3])
    if not np.isfinite(sigma_rot) or sigma_rot > MAX_SIGMA_DEG or guessed:
        if _largest_sigma_deg(held[:3, :3]) <= MAX_SIGMA_DEG:
            what = ("" if skew_prior is None else f", even with the line's skew {skew_prior.describe()}")
            raise MountingUnobservable(
                f"the tumble cannot tell the magnetometer's time skew from a turned sensor{what} (mounting ±"
                f"{_shown(sigma_rot)}° 1σ, ±{MAX_SIGMA_DEG:g}° needed): turn the unit about more than one axis "
                "(a hand's tumble, or a gimbal whose axes change speed)"
                + ("" if skew_prior is not None else ", or give the line's skew (the product's time_skew)"))
        raise MountingUnobservable(f"the attitudes seen determine the mounting only to ±{_shown(sigma_rot)}° "
                                   f"(1σ; ±{MAX_SIGMA_DEG:g}° needed): tumble through more orientations")
    seen = gravity(skew)
    angles = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", seen, m @ rotation.T), -1, 1)))
    return MountingEstimate(data_to_body=rotation, sigma_deg=sigma_rot, inclination_deg=float(np.degrees(inclination)),
                            inclination_sigma_deg=sigma_incl,
                            angle_rms_deg=float(np.sqrt(np.mean((angles - np.mean(angles)) ** 2))),
                            pairs=len(m), skew_ms=skew, skew_sigma_ms=float(np.sqrt(max(cov[4, 4], 0.0))),
                            own_skew_ms=own_skew, own_skew_sigma_ms=own_sigma, prior=skew_prior)


def reading_span_ms(t_mag_ms: NDArray) -> float:
    """How far one magnetometer reading reaches either side of the instant it is paired at: its read period
    (the median step between distinct stamps) — a firmware that averages hands on the time since its last
    read, centred on the pairing instant, and one that does not is still stamped up to a period late."""
    steps = np.diff(np.unique(np.asarray(t_mag_ms, float)))
    return float(np.median(steps)) if len(steps) else 0.0


def _shown(sigma_deg: float) -> str:
    return f"{sigma_deg:.1f}" if np.isfinite(sigma_deg) and sigma_deg < 1e4 else "∞"


def _information(track: GravityTrack, m: NDArray, t: NDArray, rotation: NDArray, inclination: float, skew: float,
                 resid: NDArray, reach_ms: float) -> tuple[NDArray, bool]:
    """``JᵀJ`` of the cosine residuals in (rotation vector, inclination, skew), each row weighted as the
    robust fit weighed it.  The skew's column is the gravity's turn over a window as long as the motion
    allows (:data:`TURN_WINDOW_RAD`), and its own entry is the product of two such columns, each from
    every other accelerometer reading: the two carry the same motion and independent noise, so the
    product carries the motion's information and, on average, none of the noise's (a column squared
    took the noise, differentiated, for information — see the module's docstring).  ``reach_ms``: what a
    magnetometer reading spans either side (no turn across a jerk is read within it)."""
    seen = unit_rows(track.accel_at(t + skew))
    body = m @ rotation.T
    weight = (1.0 + (np.asarray(resid, float) / ROBUST_SCALE) ** 2) ** -0.25  # soft-L1's IRLS weight, its root
    halves = [GravityTrack.of(track.t_ms[k::2], track.accel[k::2]) for k in (0, 1)]
    shortest = TURN_WINDOW_PERIODS * max(h.period_ms for h in halves)
    rate = float(np.median(np.linalg.norm(_turn(track, t + skew, shortest), axis=1)))
    half = min(max(TURN_WINDOW_RAD / max(rate, 1e-9), shortest), TURN_WINDOW_MAX_MS)
    # rows whose window reaches past either half's readings are left out whole: a turn clipped at the
    # stream's end is not the motion's, and a row that says "the skew does nothing here" is information
    inside = np.all([(t + skew - half >= h.t_ms[0]) & (t + skew + half <= h.t_ms[-1]) for h in halves], axis=0)
    inside &= ~track.near_jerk(t + skew, half + reach_ms)  # a turn across a jerk is not the motion's
    weight = np.where(inside, weight, 0.0)
    skew_a, skew_b = (np.einsum("ij,ij->i", _turn(h, t + skew, half), body) * weight for h in halves)
    jac = np.column_stack([np.cross(body, seen), np.full(len(m), np.cos(inclination))]) * weight[:, None]
    information = np.zeros((5, 5))
    information[:4, :4] = jac.T @ jac
    information[:4, 4] = information[4, :4] = jac.T @ (skew_a + skew_b) / 2.0
    information[4, 4] = float(skew_a @ skew_b)
    # What the skew adds beyond the mounting (the Schur complement) must stand out of the noise of its own
    # estimate: the two columns' difference is their noise, and a product of noises is as often large as
    # small.  Below SKEW_EVIDENCE of its standard error the tumble is taken to say nothing of the skew
    # (``False``: the caller then takes it as anywhere in the search, so that the mounting's σ holds what
    # the skew can move it by — all on a two-axis gimbal, next to nothing on a turntable's spins).
    explained = float(information[4, :4] @ np.linalg.lstsq(information[:4, :4], information[:4, 4], rcond=None)[0])
    mean, diff = (skew_a + skew_b) / 2.0, skew_a - skew_b
    noise = float(np.sqrt(np.sum((mean * diff) ** 2) + np.sum((diff**2 / 2.0) ** 2)))
    if information[4, 4] - explained < SKEW_EVIDENCE * noise:
        information[4, 4] = explained
    return information, information[4, 4] > explained


def _turn(track: GravityTrack, when_ms: NDArray, half_ms: float) -> NDArray:
    """The gravity's direction's rate of change (per ms), a central difference over ±``half_ms``."""
    later, earlier = unit_rows(track.accel_at(when_ms + half_ms)), unit_rows(track.accel_at(when_ms - half_ms))
    return (later - earlier) / (2.0 * half_ms)


def _covariance(information: NDArray) -> NDArray:
    """The inverse of an information matrix; ∞ on the diagonal of each parameter in a direction it
    leaves open (no information at all)."""
    scale = np.sqrt(np.maximum(np.diag(information), 1e-300))
    values, vectors = np.linalg.eigh(information / np.outer(scale, scale))
    open_ = values <= 1e-9 * max(values.max(), 1e-300)  # none, or less than none (a noisy estimate of none)
    cov = (vectors[:, ~open_] / values[~open_]) @ vectors[:, ~open_].T / np.outer(scale, scale)
    if open_.any():
        cov[np.diag_indices_from(cov)] = np.where(np.abs(vectors[:, open_]).max(axis=1) > 1e-6, np.inf,
                                                  np.diag(cov))
    return cov


def _joined(prior: SkewPrior, information: NDArray, rotation: NDArray, inclination: float, skew: float,
            polish) -> tuple[NDArray, float, float, NDArray]:
    """The tumble's estimate joined with the prior on the skew: the Gaussian update moves the skew and,
    through what the tumble correlates with it, the mounting and inclination; then the mounting and
    inclination are refined at that skew.  Returns them with the posterior covariance."""
    from scipy.spatial.transform import Rotation

    prior_information = np.zeros_like(information)
    prior_information[4, 4] = 1.0 / prior.sigma_ms**2
    cov = np.linalg.inv(information + prior_information)
    step = cov[:, 4] * (prior.skew_ms - skew) / prior.sigma_ms**2
    rotation = Rotation.from_rotvec(step[:3]).as_matrix() @ rotation
    inclination, skew = inclination + float(step[3]), skew + float(step[4])
    rotation, inclination = polish(rotation, inclination, skew)
    return rotation, inclination, skew, cov


def _polished(m: NDArray, seen: NDArray, rotation: NDArray, inclination: float) -> tuple[NDArray, float]:
    """The mounting and inclination refined with the pairing (the skew) held."""
    from scipy.optimize import least_squares
    from scipy.spatial.transform import Rotation

    def residuals(p: NDArray) -> NDArray:
        r = Rotation.from_rotvec(p[:3]).as_matrix() @ rotation
        return np.einsum("ij,ij->i", seen, m @ r.T) + np.sin(p[3])

    fit = least_squares(residuals, np.array([0.0, 0.0, 0.0, inclination]), loss="soft_l1", f_scale=ROBUST_SCALE,
                        x_scale=0.01)
    return (Rotation.from_rotvec(fit.x[:3]).as_matrix() @ rotation,
            float(np.arcsin(np.clip(np.sin(fit.x[3]), -1.0, 1.0))))


def _largest_sigma_deg(cov: NDArray) -> float:
    """1σ of a rotation's least certain axis (degrees) from its rotation-vector covariance."""
    if not np.all(np.isfinite(cov)):
        return float("inf")
    return float(np.degrees(np.sqrt(max(np.linalg.eigvalsh(cov).max(), 0.0))))
