"""When the INAV backend says its readings were taken: INAV answers ``MSP_RAW_IMU`` with the compass and
accelerometer as its serial task handles the request, so a reading belongs to the request's departure plus
the link's own transit — not to the middle of a round trip the station itself lengthened by taking the
answer late (its running fit holding the interpreter, a loaded PC).

The clock here is the test's own: the link takes the readings one millisecond after each request leaves,
and the station picks every third answer up 60 ms late, as it does while the running fit computes."""

from __future__ import annotations

import numpy as np

from magline.core.station.schema import Product
from magline.plugins.inav import dut as inav_dut
from magline.plugins.inav.dut import InavDut
from magline.plugins.inav.link import ImuReading
from magline.plugins.inav.options import InavOptions

ONE_WAY_S = 0.001
LATE_TAKEN_S = 0.060


class Clock:
    """``time.monotonic`` and ``time.sleep`` for the backend's module: time passes only when told."""

    def __init__(self) -> None:
        self.now = 1000.0

    def monotonic(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.now += max(seconds, 0.0)


class LateTakenLink:
    """Answers each ``MSP_RAW_IMU`` with readings taken ``ONE_WAY_S`` after the request left; the answer
    is back after another ``ONE_WAY_S``, and every third one sits ``LATE_TAKEN_S`` more before the station
    takes it.  Each answer carries a new compass reading, so every request is a reading."""

    def __init__(self, clock: Clock) -> None:
        self.clock, self.taken_at, self.count = clock, [], 0

    def imu(self) -> ImuReading:
        self.count += 1
        self.taken_at.append(self.clock.now + ONE_WAY_S)
        self.clock.now += 2 * ONE_WAY_S + (LATE_TAKEN_S if self.count % 3 == 0 else 0.0)
        return ImuReading(np.array([0.0, 0.0, -9.8]), np.array([100.0 + self.count, 200.0, 300.0]))


def test_readings_are_stamped_when_the_board_took_them_not_when_the_station_picked_the_answer_up(monkeypatch):
    clock = Clock()
    monkeypatch.setattr(inav_dut, "time", clock)
    dut = InavDut(Product(backend="inav", connection="tcp:127.0.0.1:1"), InavOptions())
    link = dut.link = LateTakenLink(clock)
    stream = dut.samples(50.0)
    start = clock.now
    chunks = [next(stream) for _ in range(8)]
    stamps = np.concatenate([c.t_ms for c in chunks])
    accel_stamps = np.concatenate([c.imu.t_ms for c in chunks])
    truth = (np.array(link.taken_at[:len(accel_stamps)]) - start) * 1000.0
    assert len(stamps) >= 30 and np.isin(stamps, accel_stamps).all()  # a compass reading: its answer's instant
    # the middle of each round trip put every third answer 30 ms late; the departure plus the least transit
    # puts each where the board took it
    assert np.max(np.abs(accel_stamps - truth)) < 1e-6
