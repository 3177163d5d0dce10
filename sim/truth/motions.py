"""Operator / fixture motions as sequences of field directions in the body frame.

Each motion returns unit vectors: the direction of the local field as the rotating unit sees it.
Smooth motions are integrated from an angular-velocity profile with scipy's Rotation, like a hand
tumble or a gimbal would produce, including the wobble of a human hand.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation, Slerp

Motion = Callable[[int, np.random.Generator, NDArray], NDArray]


def _uniform(n: int, rng: np.random.Generator) -> NDArray:
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def full_sphere(n: int, rng: np.random.Generator, field_dir: NDArray) -> NDArray:
    """Independent, uniformly spread directions (an ideal tumble)."""
    return _uniform(n, rng)


def hand_tumble(n: int, rng: np.random.Generator, field_dir: NDArray, wobble_deg: float = 6.0) -> NDArray:
    """An operator's tumble: the field sweeps along great circles through well-spread waypoints.

    Waypoints are a randomly rotated Fibonacci set visited in a nearest-neighbour tour (what a
    trained operator does: "each face, then the corners"), with a smooth hand wobble on top.
    """
    way = _tour(n, rng)
    k = len(way)
    seg, frac = _legs(n, k)
    a, b = way[seg], way[seg + 1]
    omega = np.arccos(np.clip(np.einsum("ij,ij->i", a, b), -1.0, 1.0))[:, None]
    sin_o = np.maximum(np.sin(omega), 1e-9)
    path = (np.sin((1 - frac[:, None]) * omega) * a + np.sin(frac[:, None] * omega) * b) / sin_o
    path = _hand_wobble(n, rng, wobble_deg).apply(path)
    return path / np.linalg.norm(path, axis=1, keepdims=True)


def _tour(n: int, rng: np.random.Generator) -> NDArray:
    """Well-spread directions (a randomly turned Fibonacci set, one per 25 readings, at least 14) in a
    nearest-neighbour tour from a random one: a trained operator's "each face, then the corners"."""
    k = max(14, n // 25)
    base = Rotation.random(random_state=rng).apply(_fibonacci(k))
    order = [int(rng.integers(k))]
    while len(order) < k:
        rest = [i for i in range(k) if i not in order]
        order.append(max(rest, key=lambda i: base[i] @ base[order[-1]]))
    return base[order]


def _legs(n: int, k: int) -> tuple[NDArray, NDArray]:
    """Each of ``n`` readings' leg of a ``k``-waypoint tour, and how far along it."""
    seg = np.minimum((np.arange(n) * (k - 1)) // n, k - 2)
    return seg, (np.arange(n) * (k - 1) / n) - seg


def _hand_wobble(n: int, rng: np.random.Generator, wobble_deg: float) -> Rotation:
    """A hand's smooth wobble over ``n`` readings: three sines of ``wobble_deg``, 3–9 times a tumble."""
    t = np.linspace(0, 2 * np.pi, n)
    return Rotation.from_rotvec(np.deg2rad(wobble_deg) * np.column_stack(
        [np.sin(t * f + rng.uniform(0, 6.3)) for f in rng.uniform(3.0, 9.0, size=3)]))


def hand_tour_attitudes(n: int, rng: np.random.Generator, wobble_deg: float = 6.0) -> Rotation:
    """Body → NED of an operator's tumble as :func:`hand_tumble` makes it, for the field *and* gravity: the
    unit turned face by face — its down direction through well-spread waypoints in a nearest-neighbour tour,
    at a random heading at each — the turn between two waypoints the shortest, with a hand's wobble."""
    downs = _tour(n, rng)
    k = len(downs)
    poses = []
    for down in downs:  # body → NED taking the waypoint's body direction onto NED down, then a heading
        tilt, _ = Rotation.align_vectors([[0.0, 0.0, 1.0]], [down])
        poses.append(Rotation.from_euler("Z", rng.uniform(0.0, 360.0), degrees=True) * tilt)
    seg, frac = _legs(n, k)
    quats = np.empty((n, 4))
    for j in range(k - 1):
        at = seg == j
        if at.any():
            quats[at] = Slerp([0.0, 1.0], Rotation.concatenate([poses[j], poses[j + 1]]))(frac[at]).as_quat()
    return Rotation.from_quat(quats) * _hand_wobble(n, rng, wobble_deg)


def _fibonacci(k: int) -> NDArray:
    i = np.arange(k) + 0.5
    z = 1.0 - 2.0 * i / k
    r = np.sqrt(1.0 - z * z)
    phi = np.pi * (1.0 + 5.0**0.5) * i
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


def cap(fraction: float) -> Motion:
    """Directions within a spherical cap holding ``fraction`` of the sphere's area.

    The cap is centred on the body's vertical axis (z), on the side the field dips to: the field
    directions seen by an operator who spins the unit in yaw but tilts it only so far.  Yaw turns
    the field about the body's vertical, so limited tilting leaves unseen a cap around the
    opposite end of that axis, whatever the field's inclination.
    """
    cos_max = 1.0 - 2.0 * fraction

    def motion(n: int, rng: np.random.Generator, field_dir: NDArray) -> NDArray:
        z = rng.uniform(cos_max, 1.0, size=n)
        phi = rng.uniform(0, 2 * np.pi, size=n)
        r = np.sqrt(1 - z * z)
        dips = 1.0 if field_dir[2] >= 0 else -1.0  # NED: positive down (northern hemisphere)
        return np.column_stack([r * np.cos(phi), r * np.sin(phi), dips * z])

    return motion


def _ring(n: int, rng: np.random.Generator, field_dir: NDArray, axis: NDArray, wobble_deg: float,
          start: Rotation) -> NDArray:
    return ring_attitudes(n, rng, axis, wobble_deg, start).inv().apply(field_dir)


def ring_attitudes(n: int, rng: np.random.Generator, axis: NDArray, wobble_deg: float,
                   start: Rotation | None = None) -> Rotation:
    """Body → NED of a unit turned once about ``axis`` over ``n`` readings from a random heading, with a
    hand's wobble (three sines of ``wobble_deg``, 2, 3 and 5 times a turn): what the field *and* gravity
    see of a spin (the stall rule reads both)."""
    angles = np.linspace(0, 2 * np.pi, n, endpoint=False) + rng.uniform(0, 2 * np.pi)
    spin = Rotation.from_rotvec(np.outer(angles, axis))
    wob = np.deg2rad(wobble_deg) * np.column_stack(
        [np.sin(angles * k + rng.uniform(0, 6.3)) for k in (2.0, 3.0, 5.0)])
    return (start or Rotation.identity()) * spin * Rotation.from_rotvec(wob)


def two_rings(n: int, rng: np.random.Generator, field_dir: NDArray, wobble_deg: float = 8.0) -> NDArray:
    """Yaw spin while level, then a roll spin: the common 'two circles' shop-floor routine."""
    first = n // 2
    level = Rotation.identity()
    a = _ring(first, rng, field_dir, np.array([0.0, 0.0, 1.0]), wobble_deg, level)
    b = _ring(n - first, rng, field_dir, np.array([1.0, 0.0, 0.0]), wobble_deg, level)
    return np.vstack([a, b])


def single_axis(n: int, rng: np.random.Generator, field_dir: NDArray, wobble_deg: float = 3.0) -> NDArray:
    """The classic mistake: spinning the unit about its vertical axis only."""
    return _ring(n, rng, field_dir, np.array([0.0, 0.0, 1.0]), wobble_deg, Rotation.identity())


# ten of the cradle tilts a turntable's operator is asked for (core/motion/tilts.py's COVERAGE_TILTS): pitch nose
# up, roll right side down, degrees
CRADLE_TILTS = ((0, 0), (0, 180), (0, 45), (0, -90), (90, 0), (0, -135), (-45, 0), (45, 180), (0, 90), (-90, 0))


def cradle_turns(n: int, rng: np.random.Generator, field_dir: NDArray, hold: float = 1 / 7) -> NDArray:
    """A turntable's units: one revolution about the vertical at each cradle tilt, in a random order,
    and the cradle held still in its last attitude while the operator's hands are on it (``hold`` of
    each ring).  Why: rings about a centre that only their union determines are the readings whose
    live coverage and the coverage of a thinned attempt part ways."""
    return cradle_attitudes(n, rng, hold).inv().apply(field_dir)


def cradle_attitudes(n: int, rng: np.random.Generator, hold: float = 1 / 7) -> Rotation:
    """Body → NED of :func:`cradle_turns`' units."""
    order = rng.permutation(len(CRADLE_TILTS))
    per = max(8, n // len(order))
    turning = int(per * (1.0 - hold))
    rows = []
    for index in order:
        pitch, roll = CRADLE_TILTS[index]
        cradle = Rotation.from_euler("YX", [pitch, roll], degrees=True)
        angles = np.linspace(0.0, 360.0, turning, endpoint=False)
        turned = np.concatenate([angles, np.full(per - turning, angles[-1])])[:, None]
        rows.append((Rotation.from_euler("Z", turned, degrees=True) * cradle).as_quat())
    quats = np.vstack(rows)
    quats = np.vstack([quats, np.repeat(quats[-1:], max(0, n - len(quats)), axis=0)])[:n]
    return Rotation.from_quat(quats)


MOTIONS: dict[str, Motion] = {
    "cradle_turns": cradle_turns,
    "full_sphere": full_sphere,
    "hand_tumble": hand_tumble,
    "hemisphere": cap(0.5),
    "cap30": cap(0.30),
    "two_rings": two_rings,
    "single_axis": single_axis,
}


def motion_directions(name: str, n: int, rng: np.random.Generator, field_dir: NDArray) -> NDArray:
    """Body-frame unit field directions for the named motion."""
    try:
        motion = MOTIONS[name]
    except KeyError:
        raise ValueError(f"unknown motion {name!r}; known: {', '.join(sorted(MOTIONS))}") from None
    return motion(n, rng, np.asarray(field_dir, float) / np.linalg.norm(field_dir))
