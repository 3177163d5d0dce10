"""The attitudes the simulated fixtures and operators turn a unit through (body → NED).

Why one module: the simulated flight controllers, the simulated gimbal, the synthetic tumbles of the
tests and the benchmarks must turn the unit the same way, so that a figure measured on one holds for
the others.

Why the attitude is built as three turns and not as "the smallest turn that shows the field in that
body direction": that smallest turn makes gravity a function of the field's direction alone (two
degrees of freedom, where a hand or a three-axis gimbal has three) and flips the unit through 180° in
an instant where the spiral passes opposite the field.  On such a path a delay between the
magnetometer and the accelerometer is indistinguishable from a turned sensor, so no test could tell a
mounting from a time skew (issue 50).  Here the field's direction in the body follows the same spiral
(azimuth ``φ`` spinning, polar angle ``θ`` sweeping pole to pole), and the unit also rocks about the
field line by ``ψ`` — which changes what the accelerometer sees and leaves the magnetometer's
readings exactly as they were.
"""

from __future__ import annotations

import functools
import math
from types import ModuleType

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

SWEEP_S = 8.0  # a full pole-to-pole sweep of the tumble at speed 1
SPIN_RAD_S = 2 * np.pi * 0.9  # the field's azimuth in the body: 0.9 turns a second at speed 1
ROCK_RAD = np.radians(45.0)  # the rocking about the field line: amplitude …
ROCK_PERIOD_S = 2.0  # … and period at speed 1
GIMBAL_STEPS = 8  # a gimbal's pitch steps per sweep
DEFAULT_FIELD_DIR = np.array([0.47, 0.0, 0.88])


def spiral_angles(t: float | NDArray, stepped: bool = False) -> tuple[NDArray, NDArray]:
    """The field's azimuth ``φ`` and polar angle ``θ`` in the body at motion time ``t``: a spherical
    spiral sweeping pole to pole and back every ``2·SWEEP_S``; ``stepped``: the polar angle in
    ``GIMBAL_STEPS`` steps (a gimbal's pitch), the azimuth continuous."""
    t = np.asarray(t, float)
    phase = (t / SWEEP_S) % 2.0
    u = np.where(phase <= 1.0, phase, 2.0 - phase)  # 0..1..0
    if stepped:
        u = (np.floor(u * GIMBAL_STEPS) + 0.5) / GIMBAL_STEPS
    return SPIN_RAD_S * t, np.arccos(np.clip(1.0 - 2.0 * u, -1.0, 1.0))


def field_frame(field_dir: NDArray | None) -> Rotation:
    """A fixed turn taking the NED field direction onto +Z (the spiral's pole)."""
    return Rotation.from_quat(_field_frame_quat(DEFAULT_FIELD_DIR if field_dir is None else field_dir))


def _field_frame_quat(field_dir: NDArray) -> NDArray:
    f = np.asarray(field_dir, float)
    return _frame_towards(*(f / np.sqrt(f @ f)).tolist())


@functools.lru_cache(maxsize=64)
def _frame_towards(north: float, east: float, down: float) -> NDArray:
    """Why cached: a simulated board asks for its attitude at every sample it averages, and aligning the
    vectors anew each time was half of the simulator's CPU (a station's field stays put)."""
    turn, _ = Rotation.align_vectors([[0.0, 0.0, 1.0]], [[north, east, down]])
    quat = turn.as_quat()
    quat.flags.writeable = False  # shared by every caller of the cache
    return quat


Quaternion = tuple  # (x, y, z, w), scipy's order; each component a float, or an array for many instants


def _about(axis: int, angle: float | NDArray, trig: ModuleType) -> Quaternion:
    """The turn by ``angle`` about body axis ``axis`` (0, 1, 2: x, y, z)."""
    half_sin, zero = trig.sin(angle / 2.0), angle * 0.0
    return (*(half_sin if i == axis else zero for i in range(3)), trig.cos(angle / 2.0))


def _product(a: Quaternion, b: Quaternion) -> Quaternion:
    """The Hamilton product ``a ⊗ b`` (scipy's ``Rotation(a) * Rotation(b)``: ``b`` turns first)."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz)


def spiral_attitude(t: float | NDArray, field_dir: NDArray | None = None, *, stepped: bool = False,
                    rock: bool = True) -> Rotation:
    """Body → NED at motion time ``t`` (seconds at speed 1; scalar or array): the field seen in the
    body follows the spiral of :func:`spiral_angles`, and the unit rocks ``±ROCK_RAD`` about the field
    line (``rock=False``: it does not, for a two-axis fixture).

    NED → body is ``Rz(φ)·Ry(θ)·Rz(ψ)·F`` (``F`` the field's frame), built as one quaternion product in
    plain floats for one instant, because a simulated board asks for it at every sample: four
    ``Rotation`` objects composed per call were a third of the simulator's CPU."""
    scalar = np.ndim(t) == 0
    x, y, z, w = _ned_to_body_quat(t, field_dir, stepped, rock)
    body_to_ned = np.array([-x, -y, -z, w])  # the inverse turn: the conjugate
    return Rotation.from_quat(body_to_ned if scalar else body_to_ned.T)


def spiral_ned_to_body(t: float, field_dir: NDArray | None = None, *, stepped: bool = False) -> NDArray:
    """The matrix turning an NED vector into the body at motion time ``t`` (one instant): the transpose of
    :func:`spiral_attitude`'s matrix, worked out from the same quaternion in plain floats.  Why: a board
    turns the field and gravity into its body for every message it streams, and scipy's ``Rotation``
    (made, then turned into a matrix) was most of that cost."""
    x, y, z, w = _ned_to_body_quat(float(t), field_dir, stepped, True)
    return np.array([[1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - z * w), 2.0 * (x * z + y * w)],
                     [2.0 * (x * y + z * w), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - x * w)],
                     [2.0 * (x * z - y * w), 2.0 * (y * z + x * w), 1.0 - 2.0 * (x * x + y * y)]])


def _ned_to_body_quat(t: float | NDArray, field_dir: NDArray | None, stepped: bool, rock: bool) -> Quaternion:
    """NED → body of :func:`spiral_attitude` as a quaternion (x, y, z, w), of floats for one instant."""
    if np.ndim(t) == 0:
        t, trig = float(t), math
        phase = (t / SWEEP_S) % 2.0
        u = phase if phase <= 1.0 else 2.0 - phase
        if stepped:
            u = (math.floor(u * GIMBAL_STEPS) + 0.5) / GIMBAL_STEPS
        phi, theta = SPIN_RAD_S * t, math.acos(min(1.0, max(-1.0, 1.0 - 2.0 * u)))
    else:
        t, trig = np.asarray(t, float), np
        phi, theta = spiral_angles(t, stepped)
    psi = ROCK_RAD * trig.sin(2.0 * math.pi * t / ROCK_PERIOD_S) if rock else phi * 0.0
    frame = tuple(_field_frame_quat(DEFAULT_FIELD_DIR if field_dir is None else field_dir).tolist())
    return _product(_product(_product(_about(2, phi, trig), _about(1, theta, trig)), _about(2, psi, trig)), frame)


# A two-axis gimbal at constant rates (speed 1): its outer axis vertical, its inner axis the unit's pitch.
# Rates whose ratio is no simple fraction, so the field's direction in the body does not retrace one curve
# (with the outer axis vertical the two caps about the pitch axis stay unseen where the field dips
# steeply: 63 % of 100 bins at a 60° dip); together 188°/s.
TWO_AXIS_OUTER_DPS, TWO_AXIS_INNER_DPS = 160.0, 99.0


def two_axis_attitude(t: float | NDArray, outer_dps: float = TWO_AXIS_OUTER_DPS,
                      inner_dps: float = TWO_AXIS_INNER_DPS) -> Rotation:
    """Body → NED at ``t`` on a two-axis gimbal turning both axes at constant rates: ``Rz(outer·t) ·
    Ry(inner·t)``.  Why the simulators have it: on this motion a time skew ``δ`` between the
    magnetometer and the accelerometer is exactly a turn of the sensor by ``inner·δ`` about the pitch
    axis (gravity sees the inner axis only), so a station that finds the skew from the tumble alone
    cannot tell it from a turned sensor; a hand's rocking tumble keeps the two apart."""
    t = np.asarray(t, float)
    return Rotation.from_euler("ZY", np.stack([outer_dps * t, inner_dps * t], axis=-1), degrees=True)


def spiral_direction(t: float | NDArray, stepped: bool = False) -> NDArray:
    """The field's unit direction in the body at motion time ``t`` (what the magnetometer sees)."""
    phi, theta = spiral_angles(t, stepped)
    return np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=-1)


def hand_attitudes(rng: np.random.Generator, seconds: float, rate_dps: float,
                   step_s: float = 0.005) -> tuple[NDArray, Rotation]:
    """An operator's free tumble on a grid of ``step_s``: ``(t_s, body → NED)``.

    The body's angular velocity is a smooth random process (a few slow sines per axis, 0.03–0.4 Hz)
    scaled to a mean rate of ``rate_dps``: the turning axis wanders through the body as a hand's does,
    which a time skew between two sensors cannot imitate."""
    t = np.arange(0.0, seconds + 0.5, step_s)
    rate = np.zeros((len(t), 3))
    for axis in range(3):
        for _ in range(4):
            rate[:, axis] += rng.normal() * np.sin(2 * np.pi * rng.uniform(0.03, 0.4) * t + rng.uniform(0, 2 * np.pi))
    rate *= np.radians(rate_dps) / np.mean(np.linalg.norm(rate, axis=1))
    steps = Rotation.from_rotvec(rate[:-1] * step_s).as_quat()  # x, y, z, w
    quats = np.empty((len(t), 4))
    quats[0] = Rotation.random(random_state=rng).as_quat()
    for k, (x2, y2, z2, w2) in enumerate(steps):  # q ← q · step (the body turns by its own rate)
        x1, y1, z1, w1 = quats[k]
        quats[k + 1] = (w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2, w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                        w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2, w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2)
    return t, Rotation.from_quat(quats)
