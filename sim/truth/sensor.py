"""A magnetometer with known hard iron, soft iron, noise, range and quantisation.

Truth convention matches the fit: the calibrated field is ``S·(m − h)``, so a sensor with truth
(h, S) reads ``m = S⁻¹·b + h`` for a body-frame field ``b``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation


def earth_field_ned(field_ut: float, inclination_deg: float, declination_deg: float = 0.0) -> NDArray:
    """Local field vector (north, east, down) in µT."""
    inc, dec = np.deg2rad(inclination_deg), np.deg2rad(declination_deg)
    return field_ut * np.array([np.cos(inc) * np.cos(dec), np.cos(inc) * np.sin(dec), np.sin(inc)])


@dataclass
class SensorTruth:
    hard_iron_ut: NDArray
    soft_iron: NDArray  # the *calibration* matrix S (symmetric, positive definite)
    noise_ut: float = 0.3
    range_ut: float | None = None
    quantum_ut: float = 0.0

    def read(self, b_body_ut: NDArray, rng: np.random.Generator) -> NDArray:
        """Raw readings for body-frame fields, with noise, quantisation and clipping."""
        m = np.linalg.solve(self.soft_iron, np.asarray(b_body_ut, float).T).T + self.hard_iron_ut
        m = m + rng.normal(scale=self.noise_ut, size=m.shape)
        if self.quantum_ut > 0:
            m = np.round(m / self.quantum_ut) * self.quantum_ut
        if self.range_ut is not None:
            m = np.clip(m, -self.range_ut, self.range_ut)
        return m


def random_truth(rng: np.random.Generator, *, max_offset_ut: float = 200.0, max_axis_ratio: float = 1.3,
                 noise_ut: float = 0.3, gain_sigma: float = 0.02) -> SensorTruth:
    """A plausible flight-controller distortion.

    Offset uniform up to ±max per axis; soft iron with the given largest axis ratio, random
    principal axes, and an overall gain (raw field radius over true field) that is log-normal
    with ``gain_sigma`` — sensors are trimmed for gain, so it stays within a few percent.
    """
    h = rng.uniform(-max_offset_ut, max_offset_ut, size=3)
    half = np.log(max_axis_ratio) / 2.0
    log_eig = rng.uniform(-half, half, size=3)
    log_eig[np.argmin(log_eig)], log_eig[np.argmax(log_eig)] = -half, half
    log_eig += -log_eig.mean() - rng.normal(scale=gain_sigma)  # det S = 1 / gain³
    eig = np.exp(log_eig)
    q = Rotation.random(random_state=rng).as_matrix()
    return SensorTruth(hard_iron_ut=h, soft_iron=q @ np.diag(eig) @ q.T, noise_ut=noise_ut)


GRAVITY_MSS = 9.80665


def gravity_body(fields_body: NDArray, field_ned: NDArray) -> NDArray:
    """What an accelerometer at rest reads (m/s², body axes, pointing up) in an attitude that turns the
    Earth field ``field_ned`` into each body-frame field of ``fields_body`` — the smallest such turn from
    level.  Why: synthetic tumbles are drawn as field directions; the mounting check needs the gravity
    that goes with each, from the same attitude."""
    from scipy.spatial.transform import Rotation

    seen = np.asarray(fields_body, float)
    seen = seen / np.linalg.norm(seen, axis=1, keepdims=True)
    north = np.asarray(field_ned, float) / np.linalg.norm(field_ned)
    axis = np.cross(north, seen)
    sin = np.linalg.norm(axis, axis=1, keepdims=True)
    angle = np.arctan2(sin[:, 0], seen @ north)
    turn = Rotation.from_rotvec(axis / np.maximum(sin, 1e-12) * angle[:, None])  # NED → body
    return turn.apply([0.0, 0.0, -GRAVITY_MSS])
