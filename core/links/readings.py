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

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from magline.core.dut import SampleChunk
from magline.core.mounting.estimate import ImuSeries

MSS_PER_MG = 9.80665 / 1000.0  # MAVLink IMU messages carry the accelerometer in milli-g
INT16_MG_RANGE_UT = 32767 / 10.0  # the largest field an int16 milligauss MAVLink field carries


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

    ``timed=True`` (a stream whose readings are paired with other sensors by time) also holds back
    the stream's first reading.  A reading's time is the message it first appears in; the first
    message of a stream shows the sensor's latest reading, taken at an unknown time before it (up to
    one sensor period: 100 ms for ArduCopter's compass), perhaps before the unit moved at all.  A
    gimbal that starts its pattern by swinging to the start attitude put that one reading 90° away
    from the gravity it was paired with, and its single outlier held the mounting σ, and so the
    whole tumble, at its count (30 s instead of 11 s on the simulated ArduPilot).  Its copies are
    dropped as repeats; the next reading that changes is the first one taken.
    """

    repeats: int = 0  # copies dropped so far
    readings: int = 0  # distinct readings passed so far
    timed: bool = False
    _last: tuple[float, float, float] | None = field(default=None, repr=False)

    def accept(self, x: float, y: float, z: float) -> bool:
        reading = (x, y, z)
        if reading == self._last:
            self.repeats += 1
            return False
        first = self._last is None
        self._last = reading
        if first and self.timed:
            return False  # the value the stream began with: of unknown age
        self.readings += 1
        return True

    def take_repeats(self) -> int:
        """Copies dropped since the last call (what a :class:`~magline.core.dut.SampleChunk` reports)."""
        n, self.repeats = self.repeats, 0
        return n


@dataclass
class ReadingsAtRest:
    """``count`` readings of a compass for a proof at rest (after the power cycle).

    Distinct readings are taken first: a stream repeats each reading at its own rate, and its copies
    are not new readings.  But a unit at rest whose compass reads the same value in every message (a
    quiet sensor whose steps are coarser than its noise; ArduPilot's SITL compass has no noise at all)
    gives no new distinct reading however long one waits — the station waited for ever on it.  Once
    ``patience_s`` has passed, what was heard, repeats included, is what the compass reads: the same
    value, rightly, in every row."""

    count: int
    patience_s: float
    distinct: list[tuple[float, float, float]] = field(default_factory=list)
    heard: list[tuple[float, float, float]] = field(default_factory=list)
    started: float = field(default_factory=time.monotonic)
    _filter: RepeatFilter = field(default_factory=RepeatFilter, repr=False)

    def add(self, x: float, y: float, z: float) -> None:
        self.heard.append((x, y, z))
        if self._filter.accept(x, y, z):
            self.distinct.append((x, y, z))

    @property
    def patient(self) -> bool:
        """Still waiting for distinct readings (``patience_s`` not yet over)."""
        return time.monotonic() - self.started < self.patience_s

    @property
    def done(self) -> bool:
        return len(self.distinct) >= self.count or (not self.patient and len(self.heard) >= self.count)

    def rows(self) -> list[tuple[float, float, float]]:
        """The readings to prove with: ``count`` distinct ones, or else the latest ``count`` heard."""
        return self.distinct[:self.count] if len(self.distinct) >= self.count else self.heard[-self.count:]


class SensorStreams:
    """Several magnetometers and the accelerometer read from one interleaved MAVLink stream, handed
    out as :class:`~magline.core.dut.SampleChunk` s: each sensor's repeats dropped on their own, its
    int16 truncation undone on its own, the primary's readings in ``mag_ut`` and the others' in
    ``more`` (what the DUT contract asks of a backend with several sensors).

    ``to_ut(device_id, mg)`` turns one sensor's distinct readings (mG, rows, truncation undone) into
    raw µT — the place for a firmware's held calibration to be undone (ArduPilot).
    """

    def __init__(self, primary: int, sensors: list[int], to_ut: Callable[[int, NDArray], NDArray]) -> None:
        self.primary = primary
        self.sensors = list(dict.fromkeys([primary, *sensors]))
        self.to_ut = to_ut
        self.filters = {d: RepeatFilter(timed=True) for d in self.sensors}  # paired with gravity by time
        self.latest_t_ms = float("-inf")  # the newest time stamp the stream carried so far
        self.taken_at = time.monotonic()
        self._clear()

    def _clear(self) -> None:
        self.rows: dict[int, list[tuple[float, float, float]]] = {d: [] for d in self.sensors}
        self.times: dict[int, list[float]] = {d: [] for d in self.sensors}
        self.imu_t: list[float] = []
        self.imu_mg: list[tuple[float, float, float]] = []
        self.current_a: list[float] = []
        self.current_t: list[float] = []
        self.current_unmeasured = 0
        self.heard = 0  # messages of any kind since the last chunk, repeats included

    def current(self, centi_amps: float) -> None:
        """The unit's own battery current reading (BATTERY_STATUS / SYS_STATUS: centi-amps), stamped with
        the latest time the stream carried (the message itself has none).  A negative value is "not
        measured" (MAVLink's −1; PX4 sends its battery's −1 A as −100), counted, not taken as a current."""
        self.heard += 1
        if centi_amps >= 0:
            self.current_a.append(centi_amps / 100.0)
            self.current_t.append(self.latest_t_ms)
        else:
            self.current_unmeasured += 1

    def accel(self, t_ms: float, x_mg: float, y_mg: float, z_mg: float) -> None:
        """An accelerometer reading (milli-g, body axes) at ``t_ms``."""
        self.heard += 1
        self.imu_t.append(t_ms)
        self.imu_mg.append((x_mg, y_mg, z_mg))
        self.latest_t_ms = max(self.latest_t_ms, t_ms)

    def mag(self, device_id: int, t_ms: float, x_mg: float, y_mg: float, z_mg: float) -> None:
        """A magnetometer field of a message (int16 mG); a repeat of the sensor's last reading is dropped."""
        self.latest_t_ms = max(self.latest_t_ms, t_ms)
        self.heard += 1
        if self.filters[device_id].accept(x_mg, y_mg, z_mg):
            self.rows[device_id].append((x_mg, y_mg, z_mg))
            self.times[device_id].append(t_ms)

    def ready(self, chunk: int, within_s: float | None = None) -> bool:
        """``chunk`` readings of the primary gathered — or, ``within_s``, whatever arrived once that long has
        passed since the last chunk: a 10 Hz compass fills ten readings in a second, and a current sweep
        waiting on whole seconds took twice as long as its readings.

        Why also a chunk without a new reading (its repeats, accelerometer and current only): the
        station's deadlines are checked between chunks.  A compass that reads the same value in every
        message (stuck, or at rest with steps coarser than its noise: ArduCopter's SITL compass has no
        noise) gave no chunk while the messages kept coming, and a current sweep waited for ever."""
        have = len(self.rows[self.primary])
        waited = within_s is not None and time.monotonic() - self.taken_at >= within_s
        return have >= chunk or (waited and (have > 0 or self.heard > 0))

    def take(self) -> SampleChunk:
        """What arrived since the last call, as one chunk."""
        def readings(device_id: int) -> SampleChunk:
            mg = untruncate_mg(np.array(self.rows[device_id], float).reshape(-1, 3))
            return SampleChunk(mag_ut=self.to_ut(device_id, mg), t_ms=np.array(self.times[device_id]),
                               repeats=self.filters[device_id].take_repeats())

        chunk = readings(self.primary)
        chunk.more = {d: readings(d) for d in self.sensors if d != self.primary}
        if self.imu_t:
            chunk.imu = ImuSeries(t_ms=np.array(self.imu_t), accel_mss=np.array(self.imu_mg, float) * MSS_PER_MG)
        chunk.current_a = np.array(self.current_a, float)
        chunk.current_t_ms = np.array(self.current_t, float)
        chunk.current_unmeasured = self.current_unmeasured
        self.taken_at = time.monotonic()
        self._clear()
        return chunk
