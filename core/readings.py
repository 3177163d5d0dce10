"""From a MAVLink stream to sensor readings: drop repeated readings, undo the int16 truncation.

Why this exists: autopilots send a stream at the rate asked for, whatever the sensor's own output
rate.  ArduCopter reads its compass at about 10 Hz, so RAW_IMU at 50 Hz carries each reading about
five times; PX4's SCALED_IMU repeats the latest ``sensor_mag`` sample at the IMU's rate with a fresh
timestamp.  Taken as independent samples, the copies inflate every statistic of the fit by the
repeat factor (its noise estimate, σ, drift test and refusal thresholds).  Neither message carries
the magnetometer's own sample time, so an exact repeat of all three axes is taken as a repeat (two
distinct readings equal to the milligauss on all three axes while the unit turns are rare, and
dropping one costs nothing).

Both firmwares fill the int16 milligauss fields by a C conversion from float, which truncates
toward zero: every axis reads on average 0.5 mG short in magnitude (0.1–0.2 % of the field, a
soft-iron scale error against a reference).  :func:`untruncate_mg` undoes that on average.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray


def untruncate_mg(values_mg: NDArray) -> NDArray:
    """The expected true value of int16 fields filled by truncation toward zero (C float → int).

    A non-zero integer ``k`` came from a value in ``[k, k+1)`` (or ``(k−1, k]`` when negative):
    its mean is ``k ± 0.5``.  Zero came from ``(−1, 1)``, whose mean is zero.
    """
    v = np.asarray(values_mg, float)
    return v + 0.5 * np.sign(v)


@dataclass
class RepeatFilter:
    """Passes each sensor reading once and counts the copies it dropped.

    ``accept(x, y, z)`` is False for a reading identical on all three axes to the last one passed.
    """

    repeats: int = 0  # copies dropped so far
    readings: int = 0  # distinct readings passed so far
    _last: tuple[float, float, float] | None = field(default=None, repr=False)

    def accept(self, x: float, y: float, z: float) -> bool:
        reading = (x, y, z)
        if reading == self._last:
            self.repeats += 1
            return False
        self._last = reading
        self.readings += 1
        return True

    def take_repeats(self) -> int:
        """Copies dropped since the last call (what a :class:`~magline.core.dut.SampleChunk` reports)."""
        n, self.repeats = self.repeats, 0
        return n
