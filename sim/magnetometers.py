"""The simulated board's magnetometers and the attitude that turns the Earth field into readings.

Each sensor has a device id encoded as both autopilots do (bus type, bus, address, device type),
its own hard iron, symmetric soft iron, noise, quantisation and range; the truth follows the
fit's convention (``S·(m − h)`` is the field), so a test can compare what the station wrote with
what the sensor really is.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from magline.sim.truth import SensorTruth
from magline.sim.truth.attitudes import spiral_attitude, spiral_ned_to_body, two_axis_attitude

BUS_I2C, BUS_SPI = 1, 2


def device_id(bus_type: int, bus: int, address: int, devtype: int) -> int:
    """PX4 / ArduPilot device id: bits 0–2 bus type, 3–7 bus, 8–15 address, 16–23 device type."""
    return bus_type | (bus << 3) | (address << 8) | (devtype << 16)


# IST8310 on I2C bus 1 at 0x0E (external GPS mast), RM3100 on SPI bus 4, BMM150 on I2C bus 3 at 0x10
DEFAULT_IDS = (device_id(BUS_I2C, 1, 0x0E, 0x06), device_id(BUS_SPI, 4, 0x00, 0x07), device_id(BUS_I2C, 3, 0x10, 0x43))
# How often a driver publishes a new reading, by device type (bits 16–23 of the id).  These are the
# simulator's assumptions for "a sensor slower than the stream", not measured driver rates; a
# station never relies on them — it measures the rate from the distinct readings it receives.
DRIVER_RATE_HZ = {0x06: 50.0, 0x07: 100.0, 0x43: 25.0}
DEFAULT_DRIVER_RATE_HZ = 50.0


def driver_rate_hz(dev_id: int) -> float:
    return DRIVER_RATE_HZ.get(dev_id >> 16 & 0xFF, DEFAULT_DRIVER_RATE_HZ)


@dataclass
class SimMagnetometer:
    """One sensor: its id and its distortion (µT, fit convention)."""

    device_id: int
    hard_iron_ut: NDArray
    soft_iron: NDArray
    noise_ut: float = 0.3
    range_ut: float = 1600.0
    external: bool = True
    misalignment_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)  # sensor axes vs body, rotation vector
    # how the sensor is really mounted, as a firmware orientation value (ArduPilot SITL's SIM_MAGn_ORIENT):
    # its readings are the body field turned by the inverse of that rotation
    mounting: int = 0
    # the field the board's power wiring adds at this sensor per amp (body axes, µT/A): None draws a plausible
    # one (a compass on the board sees far more than one on a GPS mast)
    interference_ut_per_a: NDArray | None = None
    truth: SensorTruth = field(init=False)

    def __post_init__(self) -> None:
        if self.interference_ut_per_a is None:
            # drawn from the sensor's own hard iron (a board's seed made it), not from the board's rng: every
            # other draw of a seeded board stays what it was before the simulators learnt the current
            own = np.random.default_rng(np.frombuffer(np.asarray(self.hard_iron_ut, float).tobytes(), np.uint32))
            size = own.uniform(0.02, 0.08) if self.external else own.uniform(0.2, 0.5)
            direction = own.normal(size=3)
            self.interference_ut_per_a = size * direction / np.linalg.norm(direction)
        self.interference_ut_per_a = np.asarray(self.interference_ut_per_a, float)
        self.hard_iron_ut = np.asarray(self.hard_iron_ut, float)
        self.soft_iron = np.asarray(self.soft_iron, float)
        self.truth = SensorTruth(hard_iron_ut=self.hard_iron_ut, soft_iron=self.soft_iron,
                                 noise_ut=self.noise_ut, range_ut=self.range_ut)
        self.mount(self.mounting, self.misalignment_deg)

    def mount(self, mounting: int, misalignment_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> None:
        """Mount the sensor in a firmware orientation, with a small misalignment on top."""
        from magline.core.mounting import orientation_matrix

        self.mounting, self.misalignment_deg = int(mounting), tuple(misalignment_deg)
        self.rotation = (Rotation.from_matrix(orientation_matrix(self.mounting))
                         * Rotation.from_rotvec(np.deg2rad(self.misalignment_deg)))

    @property
    def rotation(self) -> Rotation:
        """The turn from the sensor's axes to the body's."""
        return self._rotation

    @rotation.setter
    def rotation(self, turn: Rotation) -> None:
        # kept as a matrix too: body rows times it are the sensor's (the inverse turn), 5 µs a reading where
        # scipy's inverse and apply took 50
        self._rotation, self._body_to_sensor = turn, turn.as_matrix()

    def read_ut(self, b_body_ut: NDArray, rng: np.random.Generator) -> NDArray:
        return self.read_samples_ut(np.atleast_2d(b_body_ut), rng)[0]

    def read_samples_ut(self, b_body_rows_ut: NDArray, rng: np.random.Generator, noiseless: bool = False) -> NDArray:
        """One raw sample for each body-frame field (rows): what a driver reads, one sample after another
        (``noiseless``: without the sensor's noise, as a simulator's compass may be)."""
        truth = replace(self.truth, noise_ut=0.0) if noiseless else self.truth
        return truth.read(np.atleast_2d(b_body_rows_ut) @ self._body_to_sensor, rng)


def default_magnetometers(count: int, rng: np.random.Generator) -> list[SimMagnetometer]:
    """``count`` sensors with distinct, plausible distortions (reproducible from ``rng``)."""
    mags = []
    for i in range(count):
        q = Rotation.random(random_state=rng).as_matrix()
        eig = np.exp(rng.uniform(-0.06, 0.06, size=3))
        mags.append(SimMagnetometer(device_id=DEFAULT_IDS[i], hard_iron_ut=rng.uniform(-60, 60, size=3),
                                    soft_iron=q @ np.diag(eig) @ q.T, external=(i == 0)))
    return mags


# --------------------------------------------------------------------------- attitude

MOTIONS = ("tumble", "single_axis", "gimbal", "two_axis", "still", "shared")  # shared: follow a gimbal simulator


def ned_to_body(motion: str, t: float, speed: float = 1.0, field_dir: NDArray | None = None) -> NDArray:
    """The matrix turning an NED vector into the body of :func:`attitude` (its transpose); the spiral
    motions' without scipy's ``Rotation``, which a board would make at every message it streams."""
    if motion in ("tumble", "gimbal"):
        return spiral_ned_to_body(t * speed, field_dir, stepped=motion == "gimbal")
    return attitude(motion, t, speed, field_dir).as_matrix().T


def attitude(motion: str, t: float, speed: float = 1.0, field_dir: NDArray | None = None) -> Rotation:
    """Body attitude (body → NED) at ``t`` seconds into a scripted motion.

    ``tumble`` turns the unit so the field sweeps the whole sphere in a spiral every
    ``SWEEP_S / speed`` seconds while the unit rocks about the field line (what a trained operator
    achieves; :mod:`magline.sim.truth.attitudes`); ``single_axis`` is the operator's classic mistake
    (yaw only); ``gimbal`` is a fixture (continuous yaw, stepped pitch, rocking about the field line
    as a three-axis gimbal can); ``two_axis`` is a two-axis gimbal turning both axes at constant rates
    (outer axis vertical: the motion on which a time skew is a turned sensor); ``still`` does not move.
    """
    t = t * speed
    if motion == "single_axis":
        return Rotation.from_euler("Z", 1.2 * t)
    if motion == "still":
        return Rotation.identity()
    if motion == "two_axis":
        return two_axis_attitude(t)
    if motion not in ("tumble", "gimbal"):
        raise ValueError(f"unknown motion {motion!r}; choose from {', '.join(m for m in MOTIONS if m != 'shared')}")
    return spiral_attitude(t, field_dir, stepped=motion == "gimbal")
