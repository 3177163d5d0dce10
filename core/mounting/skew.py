"""When was a magnetometer reading taken, on the accelerometer's clock?

Why this is needed: neither firmware streams a magnetometer reading with the instant it was taken.
PX4's SCALED_IMU carries the IMU's time with the latest ``sensor_mag``, which is 28–36 ms older
(PX4 v1.16 SITL against an analytic truth); on ArduCopter SITL the compass readings fit best placed
about 40 ms *after* the message they first appear in.  Paired at their stamps, a good compass tumbled
at 60°/s read 2.2–3.3° of mounting error and a fast PX4 tumble 16–20° (issue 50).

How: the skew is the shift of the magnetometer's stamps that makes the angle between gravity and the
calibrated field constant over the tumble.  A shift is *not* the same as a turned sensor as long as
the unit turns about more than one axis (a hand, a three-axis gimbal): a shift turns each reading
about the axis the unit is turning about at that instant.  This module gives the accelerometer at any
instant (a smoothing spline through its readings: a straight line between readings 30° apart cuts
the corner) and a coarse search for the shift; :mod:`magline.core.mounting.estimate` refines it together
with the mounting and states both σ.

The coarse search needs no mounting: ``gᵀ·R·m = −sin(inclination)`` is linear in the nine entries of
``R`` and the constant, so for each shift the smallest singular value of the readings' matrix
``[g⊗m, −1]`` says how well *some* matrix makes the angle constant.  With attitudes spread over the
sphere only the right rotation (up to scale) does.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from magline.core.mounting.smoothing import SmoothingSpline

SKEW_SEARCH_MS = 150.0  # the largest skew looked for, either sign (the firmwares measured: −36 … +40 ms)
SKEW_STEP_MS = 3.0  # the coarse search's step (the valley is tens of ms wide even at 1,600°/s)
COARSE_READINGS = 300
MAX_GAP_PERIODS = 3.0  # no accelerometer between readings further apart than this: nothing paired in the gap
STILL_TOLERANCE = 0.08  # |a| within 8 % of gravity: readings taken while the unit accelerated are left out
MIN_PAIRS = 30
# The accelerometer's smoothing spline's stiffness, times the stream's period cubed.  Why smooth: an
# interpolant through noisy readings is noisier at a reading than between two (where it averages
# them), so the fit preferred stamps half a period off the readings and pulled the skew there by up to
# half a period; with this stiffness the noise is the same everywhere between readings (±2 %) and a
# rotation of 30° per reading keeps its direction (a circle's is exact) and 99 % of its length.
SMOOTHING = 0.1
# A jerk: gravity turned between two accelerometer readings over JERK_FACTOR times as fast as its median rate over
# JERK_NEIGHBOURS readings either side (a gap in the stream is not a jerk), and by at least JERK_FLOOR_DEG.  Why
# left out: each sensor hands on a filtered reading (a compass the mean over its read window, an accelerometer its
# low-pass), and only while the motion is smooth over those windows do the two differ by a delay; across a jerk
# they differ by their filters' shapes, and one jerk then weighed as much as the whole tumble in the skew and the
# turn about the axis the unit spins about (ArduCopter SITL's FlightAxis clock jumps: 7–18° in one reading, and a
# good compass read 1.05° ± 0.10° turned).  A noisy still stream's largest turn among thousands is about 3.5 times
# its median (a Rayleigh spread); SITL's clock jumps stood 5 to 26 times above it, the simulated gimbal's pitch
# steps are jerks too, and a hand's bump would be one.
JERK_FACTOR = 5.0
JERK_FLOOR_DEG = 3.0
JERK_NEIGHBOURS = 25
JERK_SPREAD_PERIODS = 2.0  # how far a jerk reaches into the smoothing spline each side (accelerometer periods)


def unit_rows(v: NDArray) -> NDArray:
    return v / np.linalg.norm(v, axis=1, keepdims=True)


@dataclass
class GravityTrack:
    """The accelerometer at any instant of its stream, and whether it then saw gravity alone."""

    t_ms: NDArray  # distinct stamps, sorted
    accel: NDArray  # their readings (readings sharing a stamp averaged)
    gyro_rads: NDArray | None  # the body's rate at the same stamps, where the stream has it
    gravity: float  # |g| as the accelerometer reads it (the median magnitude)
    period_ms: float  # the stream's median period
    _spline: SmoothingSpline | None = None  # the accelerometer's smoothing spline, made on first use
    _jerks: NDArray | None = None  # the jerks' instants, found on first use

    @property
    def jerks_ms(self) -> NDArray:
        """The instants of the stream's jerks, sorted: nothing is paired near them (:data:`JERK_FACTOR`).  Found
        on first use: the halves the skew's information is read from never ask."""
        if self._jerks is None:
            self._jerks = jerk_instants_ms(self.t_ms, self.accel)
        return self._jerks

    @classmethod
    def of(cls, t_ms: NDArray, accel: NDArray, gyro_rads: NDArray | None = None) -> GravityTrack:
        stamps, where = np.unique(np.asarray(t_ms, float), return_inverse=True)
        count = np.bincount(where)[:, None]
        mean = np.zeros((len(stamps), 3))
        np.add.at(mean, where, np.asarray(accel, float))
        gyro = None
        if gyro_rads is not None and len(gyro_rads) == len(where):
            gyro = np.zeros((len(stamps), 3))
            np.add.at(gyro, where, np.asarray(gyro_rads, float))
            gyro /= count
        mean /= count
        period = float(np.median(np.diff(stamps))) if len(stamps) > 1 else float("inf")
        return cls(stamps, mean, gyro, float(np.median(np.linalg.norm(mean, axis=1))), period)

    def near_jerk(self, when_ms: NDArray, reach_ms: float) -> NDArray:
        """Which of ``when_ms`` lie within ``reach_ms`` of a jerk, or within the spline's spread of one."""
        when = np.asarray(when_ms, float)
        jerks = self.jerks_ms
        if not len(jerks):
            return np.zeros(len(when), bool)
        reach = reach_ms + JERK_SPREAD_PERIODS * self.period_ms
        after = np.searchsorted(jerks, when)
        last = len(jerks) - 1
        before, later = jerks[np.clip(after - 1, 0, last)], jerks[np.clip(after, 0, last)]
        nearest = np.minimum(np.abs(when - before), np.abs(when - later))
        return nearest <= reach

    def accel_at(self, when_ms: NDArray) -> NDArray:
        """The accelerometer at ``when_ms`` (held at the stream's ends), without :meth:`at`'s judgement of
        which instants are usable: what a fit that has already chosen its readings asks for at every step.
        Fewer than four readings make no track: zeros."""
        if len(self.t_ms) < 4:
            return np.zeros((len(np.atleast_1d(when_ms)), 3))
        if self._spline is None:  # the three axes share their stamps: one spline of three columns
            self._spline = SmoothingSpline.fit(self.t_ms, self.accel, lam=SMOOTHING * self.period_ms**3)
        return self._spline(np.clip(np.asarray(when_ms, float), self.t_ms[0], self.t_ms[-1]))

    def at(self, when_ms: NDArray, reach_ms: float = 0.0) -> tuple[NDArray, NDArray]:
        """The accelerometer at ``when_ms`` and which of those instants are usable: inside the stream,
        not in a gap, not within ``reach_ms`` (what the caller's reading spans either side) of a jerk, and
        seeing gravity alone (the unit not accelerated, not turning beyond 120°/s where the gyro says so)."""
        when = np.asarray(when_ms, float)
        t = self.t_ms
        if len(t) < 4:
            return np.zeros((len(when), 3)), np.zeros(len(when), bool)
        usable = (when >= t[0]) & (when <= t[-1])
        right = np.clip(np.searchsorted(t, when), 1, len(t) - 1)
        usable &= (t[right] - t[right - 1]) <= MAX_GAP_PERIODS * self.period_ms
        usable &= ~self.near_jerk(when, reach_ms)
        values = self.accel_at(when)
        usable &= np.abs(np.linalg.norm(values, axis=1) - self.gravity) < STILL_TOLERANCE * self.gravity
        if self.gyro_rads is not None:
            rate = np.linalg.norm(self.gyro_rads, axis=1)
            usable &= np.interp(when, t, rate) < np.radians(120.0)
        return values, usable


def jerk_instants_ms(t_ms: NDArray, accel: NDArray) -> NDArray:
    """The instants (midway between two readings) where gravity jerked (:data:`JERK_FACTOR`)."""
    if len(t_ms) < 2 * JERK_NEIGHBOURS + 2:
        return np.empty(0)
    a = np.asarray(accel, float)
    norm = np.linalg.norm(a, axis=1, keepdims=True)
    g = np.divide(a, norm, out=np.zeros_like(a), where=norm > 0)  # an empty reading (all zero) turns nothing
    turned = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", g[1:], g[:-1]), -1.0, 1.0)))
    turned[(norm[1:, 0] == 0) | (norm[:-1, 0] == 0)] = 0.0
    t = np.asarray(t_ms, float)
    rate = turned / np.maximum(np.diff(t), 1e-9)  # per ms: a gap in the stream (messages lost) turns no faster
    padded = np.pad(rate, JERK_NEIGHBOURS, mode="edge")
    local = np.median(np.lib.stride_tricks.sliding_window_view(padded, 2 * JERK_NEIGHBOURS + 1), axis=1)
    jerked = (rate > JERK_FACTOR * local) & (turned > JERK_FLOOR_DEG)
    return (t[1:][jerked] + t[:-1][jerked]) / 2.0


def constancy_cost(mag_unit: NDArray, accel_unit: NDArray) -> float:
    """How far the best linear map keeps ``gᵀ·A·m`` constant: the smallest singular value² of the
    readings' matrix per reading (the smallest eigenvalue of its 10×10 Gram matrix, which costs a
    fraction of the tall matrix's SVD)."""
    rows = np.einsum("ij,ik->ijk", accel_unit, mag_unit).reshape(len(mag_unit), 9)
    matrix = np.column_stack([rows, -np.ones(len(mag_unit))])
    return float(max(np.linalg.eigvalsh(matrix.T @ matrix)[0], 0.0) / len(mag_unit))


def coarse_skew_ms(mag_unit: NDArray, t_mag_ms: NDArray, track: GravityTrack, reach_ms: float = 0.0) -> float | None:
    """The shift of the magnetometer's stamps (ms, within ±``SKEW_SEARCH_MS``) that best keeps the
    gravity–field angle constant; None when no shift leaves enough readings to pair.  At most
    ``COARSE_READINGS`` readings, evenly spread over the tumble, take part: the search only has to
    find the valley the refinement starts in.  ``reach_ms``: what a reading spans either side (none is
    paired that near a jerk)."""
    pick = np.unique(np.linspace(0, len(mag_unit) - 1, min(len(mag_unit), COARSE_READINGS)).astype(int))
    mag_unit, t_mag_ms = mag_unit[pick], np.asarray(t_mag_ms, float)[pick]
    best: tuple[float, float] | None = None
    shifts = np.arange(-SKEW_SEARCH_MS, SKEW_SEARCH_MS + SKEW_STEP_MS / 2, SKEW_STEP_MS)
    # the accelerometer at every shift's instants in one evaluation: a hundred calls cost more than their points
    every, every_usable = track.at((shifts[:, None] + t_mag_ms[None, :]).ravel(), reach_ms)
    for k, shift in enumerate(shifts):
        rows = slice(k * len(t_mag_ms), (k + 1) * len(t_mag_ms))
        accel, usable = every[rows], every_usable[rows]
        if usable.sum() < MIN_PAIRS:
            continue
        cost = constancy_cost(mag_unit[usable], unit_rows(accel[usable]))
        if best is None or cost < best[0]:
            best = (cost, float(shift))
    return None if best is None else best[1]
