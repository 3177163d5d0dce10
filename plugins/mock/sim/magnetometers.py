"""The simulated board's magnetometers and the attitude that turns the Earth field into readings.

Each sensor has a device id encoded as both autopilots do (bus type, bus, address, device type),
its own hard iron, symmetric soft iron, noise, quantisation and range; the truth follows the
fit's convention (``S·(m − h)`` is the field), so a test can compare what the station wrote with
what the sensor really is.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from magline.core.synthetic import SensorTruth

BUS_I2C, BUS_SPI, BUS_SIMULATION = 1, 2, 4


def device_id(bus_type: int, bus: int, address: int, devtype: int) -> int:
    """PX4 / ArduPilot device id: bits 0–2 bus type, 3–7 bus, 8–15 address, 16–23 device type."""
    return bus_type | (bus << 3) | (address << 8) | (devtype << 16)


# IST8310 on I2C bus 1 at 0x0E (external GPS mast), RM3100 on SPI bus 4, BMM150 on I2C bus 3 at 0x10
DEFAULT_IDS = (device_id(BUS_I2C, 1, 0x0E, 0x06), device_id(BUS_SPI, 4, 0x00, 0x07), device_id(BUS_I2C, 3, 0x10, 0x43))


@dataclass
class SimMagnetometer:
    """One sensor: its id and its distortion (µT, fit convention)."""

    device_id: int
    hard_iron_ut: NDArray
    soft_iron: NDArray
    noise_ut: float = 0.3
    range_ut: float = 1600.0
    external: bool = True
    truth: SensorTruth = field(init=False)

    def __post_init__(self) -> None:
        self.hard_iron_ut = np.asarray(self.hard_iron_ut, float)
        self.soft_iron = np.asarray(self.soft_iron, float)
        self.truth = SensorTruth(hard_iron_ut=self.hard_iron_ut, soft_iron=self.soft_iron,
                                 noise_ut=self.noise_ut, range_ut=self.range_ut)

    def read_ut(self, b_body_ut: NDArray, rng: np.random.Generator) -> NDArray:
        return self.truth.read(np.atleast_2d(b_body_ut), rng)[0]


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

MOTIONS = ("tumble", "single_axis", "gimbal", "still")


def attitude(motion: str, t: float, speed: float = 1.0) -> Rotation:
    """Body attitude (body → NED) at ``t`` seconds into a scripted motion.

    ``tumble`` turns about all three axes at incommensurate rates, so it keeps sweeping new
    orientations for as long as it runs; ``single_axis`` is the operator's classic mistake (yaw
    only); ``gimbal`` is a two-axis fixture: continuous yaw, pitch stepping once per turn.
    """
    t = t * speed
    if motion == "tumble":
        return Rotation.from_euler("ZYX", [1.10 * t, 0.73 * t, 0.47 * t])
    if motion == "single_axis":
        return Rotation.from_euler("Z", 1.2 * t)
    if motion == "gimbal":
        turn = int(1.2 * t // (2 * np.pi))
        pitch = np.deg2rad([-75, -45, -15, 15, 45, 75, 90, -90][turn % 8])
        return Rotation.from_euler("ZYX", [1.2 * t, pitch, 0.0])
    if motion == "still":
        return Rotation.identity()
    raise ValueError(f"unknown motion {motion!r}; choose from {', '.join(MOTIONS)}")


def body_field(field_ned_ut: NDArray, motion: str, t: float, speed: float = 1.0) -> NDArray:
    """The local field as the body sees it at ``t``."""
    return attitude(motion, t, speed).inv().apply(field_ned_ut)
