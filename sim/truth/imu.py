"""A tumbling unit as its magnetometer *and* its accelerometer see it, with known truth.

Why one place: the mounting check's tests and benchmark must draw the same tumbles, so that "the
mounting is recovered to 0.3°" means one thing.  The attitude is the simulators' spiral
(:func:`magline.sim.magnetometers.attitude` follows the same path) at a careful
operator's rate; the accelerometer reads gravity plus its own noise and a hand's slow accelerations.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from magline.sim.truth.attitudes import hand_attitudes, spiral_attitude
from magline.sim.truth.sensor import GRAVITY_MSS, earth_field_ned

if TYPE_CHECKING:
    from magline.core.mounting import ImuSeries

HAND_MSS = 0.1  # RMS of the small, slow accelerations of a hand holding the unit (smoothed over 0.5 s)
ACCEL_NOISE_MSS = 0.05
RATE = 0.2  # the simulators' spiral at a fifth of its speed: about 65°/s


def tumble_with_imu(mounted: NDArray, rng: np.random.Generator, *, seconds: float = 60.0, mag_hz: float = 10.0,
                    noise_ut: float = 0.3, steady: bool = True, field_ut: float = 48.0,
                    inclination_deg: float = 62.0) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """A calibrated sensor mounted as ``mounted`` (sensor → body, ``v_body = R·v_sensor``) on a
    tumbling unit: ``(mag_ut, t_mag_ms, accel_mss, t_acc_ms)`` — its readings at ``mag_hz`` and a 50 Hz
    accelerometer.  ``steady``: a constant rate (a fixture); otherwise a hand that speeds up and slows
    down."""
    field = earth_field_ned(field_ut, inclination_deg)
    t_mag = np.arange(0.0, seconds, 1.0 / mag_hz)
    t_acc = np.arange(0.0, seconds, 0.02)
    body = _poses(t_mag, steady, field).inv().apply(field)
    mag = body @ np.asarray(mounted) + rng.normal(0.0, noise_ut, body.shape)  # rows: mountedᵀ · b
    gravity = _poses(t_acc, steady, field).inv().apply([0.0, 0.0, -GRAVITY_MSS])
    kernel = np.ones(25) / 25.0
    hand = np.column_stack([np.convolve(rng.normal(0.0, 1.0, len(t_acc)), kernel, "same") for _ in range(3)])
    hand *= HAND_MSS / hand.std()
    accel = gravity + hand + rng.normal(0.0, ACCEL_NOISE_MSS, (len(t_acc), 3))
    return mag, t_mag * 1000.0, accel, t_acc * 1000.0


def _poses(t: NDArray, steady: bool, field: NDArray) -> Rotation:
    """Body → NED attitudes along the simulators' spiral (:mod:`magline.sim.truth.attitudes`) at
    ``RATE``; unsteady: a hand that speeds up and slows down."""
    t = RATE * (t if steady else t + 1.5 * np.sin(0.8 * t))
    return spiral_attitude(t, field)


def simulator_fields(motion: str, t_s: NDArray, speed: float, field_ned: NDArray,
                     vector_ned: NDArray | None = None) -> NDArray:
    """The Earth field ``field_ned`` (or another NED vector, e.g. gravity, ``vector_ned``) in the body
    of a unit moved as the simulated flight controllers move it (``tumble``, ``gimbal`` … at
    ``speed``; their path is drawn for that field), at each time ``t_s`` (seconds).

    Why here: the agreement, early-stop and drift benchmarks and their tests must see the simulators'
    own motion, pitch steps and all, not a look-alike."""
    from magline.sim.magnetometers import attitude

    field = np.asarray(field_ned, float)
    seen = field if vector_ned is None else np.asarray(vector_ned, float)
    return np.array([attitude(motion, t, speed, field).inv().apply(seen) for t in np.atleast_1d(t_s)])


def compass_pair(rng: np.random.Generator, *, motion: str, speed: float, lag_s: float, seconds: float,
                 noise_ut: float = 0.5, turn_deg: float = 0.0, field_ut: float = 48.0, inclination_deg: float = 63.0):
    """Two calibrated 10 Hz compasses on a unit moved as a simulator moves it, the second read
    ``lag_s`` after the first (each stamped at its own instant) and turned ``turn_deg`` about the
    body's Z: ``(a, t_a_ms, b, t_b_ms, (t_imu_ms, accel_mss))`` with a 200 Hz accelerometer."""
    field = earth_field_ned(field_ut, inclination_deg)
    t_a = np.arange(0.1, seconds, 0.1) + rng.uniform(0.0, 0.1)
    t_b, t_imu = t_a + lag_s, np.arange(0.0, seconds + 0.3, 0.005)
    turn = Rotation.from_euler("Z", turn_deg, degrees=True).as_matrix()
    a = simulator_fields(motion, t_a, speed, field)
    b = simulator_fields(motion, t_b, speed, field) @ turn.T
    accel = simulator_fields(motion, t_imu, speed, field, np.array([0.0, 0.0, -GRAVITY_MSS]))
    return (a + rng.normal(0.0, noise_ut, a.shape), t_a * 1000.0, b + rng.normal(0.0, noise_ut, b.shape),
            t_b * 1000.0, (t_imu * 1000.0, accel))


def skewed_tumble(mounted: NDArray, rng: np.random.Generator, *, rate_dps: float, skew_s: float,
                  seconds: float = 40.0, mag_hz: float = 10.0, message_hz: float = 50.0, noise_ut: float = 0.3,
                  accel_noise_mss: float = 0.02, field_ut: float = 48.0,
                  inclination_deg: float = 62.0) -> tuple[NDArray, NDArray, NDArray, NDArray, NDArray]:
    """An operator's free tumble at a mean ``rate_dps`` as a firmware streams it
    (:func:`~magline.sim.truth.attitudes.hand_attitudes`): ``(mag_ut, t_mag_ms, accel_mss, t_acc_ms,
    offset_ms)`` — the last, per reading, how much later than its stamp it was really taken.

    The accelerometer is read at every message (``message_hz``) and stamped with the message's time;
    the magnetometer is read at ``mag_hz`` and each reading is stamped with the first message after
    ``skew_s`` before it was taken — so pairing a reading with the accelerometer at its stamp plus
    ``skew_s`` is right to within one message period (positive: the reading belongs later than its
    stamp, as ArduCopter's compass; negative: earlier, as PX4's sensor_mag in SCALED_IMU)."""
    field = earth_field_ned(field_ut, inclination_deg)
    t_grid, attitudes = hand_attitudes(rng, seconds, rate_dps)
    from scipy.spatial.transform import Slerp

    along = Slerp(t_grid, attitudes)
    t_msg = np.arange(0.2, seconds, 1.0 / message_hz)
    accel = along(t_msg).inv().apply([0.0, 0.0, -GRAVITY_MSS]) + rng.normal(0.0, accel_noise_mss, (len(t_msg), 3))
    taken = np.arange(0.3, seconds - 0.3, 1.0 / mag_hz) + rng.uniform(0.0, 1.0 / mag_hz)
    body = along(taken).inv().apply(field)
    mag = body @ np.asarray(mounted) + rng.normal(0.0, noise_ut, body.shape)
    due = taken - skew_s
    first = np.searchsorted(t_msg, due)
    inside = (first > 0) & (first < len(t_msg))
    stamps = t_msg[first[inside]]
    return mag[inside], stamps * 1000.0, accel, t_msg * 1000.0, (taken[inside] - stamps) * 1000.0


def two_axis_tumble(mounted: NDArray, rng: np.random.Generator, *, rate_hz: float, skew_s: float,
                    seconds: float = 25.0, outer_dps: float = 160.0, inner_dps: float = 99.0,
                    noise_ut: float = 0.3, accel_noise_mss: float = 0.05, age_jitter_s: float = 0.01,
                    field_ut: float = 48.0, inclination_deg: float = 60.0) -> tuple[NDArray, NDArray, ImuSeries]:
    """A two-axis gimbal at constant rates as PX4 streams it in SCALED_IMU (issue 61): each message carries
    the accelerometer at its stamp and the latest magnetometer reading, taken ``skew_s`` (and up to
    ``age_jitter_s`` more) before it; the messages arrive irregularly at ``rate_hz`` on average (a loaded
    host's 16 a second, a quiet one's 50).  ``(mag_ut, t_mag_ms, imu)``."""
    from magline.core.mounting import ImuSeries
    from magline.sim.truth.attitudes import two_axis_attitude

    n = max(int(seconds * rate_hz), 2)
    t = np.cumsum(rng.uniform(0.5, 1.5, n) / rate_hz)
    start = rng.uniform(0.0, 360.0 / max(outer_dps, 1e-9))

    def attitude(when: NDArray):
        return two_axis_attitude(when + start, outer_dps, inner_dps)

    accel = attitude(t).inv().apply([0.0, 0.0, -GRAVITY_MSS]) + rng.normal(0.0, accel_noise_mss, (n, 3))
    taken = t + skew_s - rng.uniform(0.0, age_jitter_s, n)
    body = attitude(taken).inv().apply(earth_field_ned(field_ut, inclination_deg))
    mag = body @ np.asarray(mounted) + rng.normal(0.0, noise_ut, (n, 3))
    return mag, t * 1000.0, ImuSeries(t_ms=t * 1000.0, accel_mss=accel)


def averaged_spiral(rng: np.random.Generator, *, clock_jump_s: float = 0.0, jump_at_s: float = 14.0,
                    seconds: float = 26.0, speed: float = 0.15, noise_ut: float = 0.06,
                    field_ut: float = 49.0, inclination_deg: float = 65.8) -> tuple[NDArray, NDArray, ImuSeries]:
    """A good, calibrated compass on the simulators' spiral as ArduCopter streams it (the SITL tier's swept
    unit, ``magline.sitl.ardupilot_flightaxis``): the compass sampled at 100 Hz and read every 100 ms as the
    mean of its samples since the last read (``drain_accumulated_samples``), the accelerometer sampled at
    1 kHz through a 20 Hz two-pole Butterworth (``INS_ACCEL_FILTER``'s ``LowPassFilter2p``), each stamped with
    the next 50 Hz message.  ``clock_jump_s``: at ``jump_at_s`` the board's clock skips that much of the motion
    (SITL's FlightAxis clock snapping back to its peer's: the unit jumps 20° in one instant).
    ``(mag_ut, t_mag_ms, imu)``."""
    from scipy.signal import butter, lfilter

    from magline.core.mounting import ImuSeries

    field = earth_field_ned(field_ut, inclination_deg)

    def attitude(board_s: NDArray) -> Rotation:
        return spiral_attitude(speed * (board_s + clock_jump_s * (board_s >= jump_at_s)) + 3.0, field)

    fine = np.arange(0.0, seconds, 0.001)
    gravity = attitude(fine).inv().apply([0.0, 0.0, -GRAVITY_MSS])
    b, a = butter(2, 20.0, fs=1000.0)
    filtered = lfilter(b, a, gravity - gravity[0], axis=0) + gravity[0]  # started settled
    t_msg = np.arange(0.2, seconds - 0.2, 0.02)
    accel = filtered[np.round(t_msg * 1000.0).astype(int)] + rng.normal(0.0, 0.02, (len(t_msg), 3))
    samples = np.arange(0.0, seconds, 0.01)
    sampled = attitude(samples).inv().apply(field)
    reads = np.arange(0.3, seconds - 0.3, 0.1) + rng.uniform(0.0, 0.1)
    mag = np.array([sampled[(samples > r - 0.1) & (samples <= r)].mean(axis=0) for r in reads])
    mag += rng.normal(0.0, noise_ut, mag.shape)
    first = np.searchsorted(t_msg, reads)
    sent = first < len(t_msg)
    return mag[sent], t_msg[first[sent]] * 1000.0, ImuSeries(t_ms=t_msg * 1000.0, accel_mss=accel)
