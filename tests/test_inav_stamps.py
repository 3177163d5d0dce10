"""When the INAV backend says its readings were taken: INAV answers ``MSP_RAW_IMU`` with the compass and
accelerometer as its serial task handles the request — somewhere inside the request's round trip.  An
answer that came back late (the station took it late, its running fit holding the interpreter; or the
board answered late) cannot be placed: it is left out, and the next answer, which carries the compass
reading INAV still holds, places it.

The clock here is the test's own: the board takes its readings one millisecond after a request leaves and
its compass holds each reading for two requests; the station picks every third answer up 60 ms late, and
the board answers every fifth 60 ms late (taken late)."""

from __future__ import annotations

import numpy as np
from stepped_clock import SteppedClock

from magline.core.station.schema import Product
from magline.plugins.inav import dut as inav_dut
from magline.plugins.inav.dut import LATE_ANSWER_S, InavDut
from magline.plugins.inav.link import ImuReading
from magline.plugins.inav.options import InavOptions

ONE_WAY_S = 0.001
LATE_S = 0.060


class LateAnsweringLink:
    """``MSP_RAW_IMU`` answered as described in the module's docstring; ``taken_at`` holds when each
    answer's readings were really taken, ``compass`` which compass reading each answer carried."""

    def __init__(self, clock: SteppedClock) -> None:
        self.clock, self.taken_at, self.compass, self.count = clock, [], [], 0

    def imu(self) -> ImuReading:
        self.count += 1
        board_late = LATE_S if self.count % 5 == 0 else 0.0
        taken = self.clock.now + ONE_WAY_S + board_late
        self.taken_at.append(taken)
        self.compass.append((self.count + 1) // 2)  # a new compass reading every second request
        station_late = LATE_S if self.count % 3 == 0 else 0.0
        self.clock.now = taken + ONE_WAY_S + station_late
        return ImuReading(np.array([0.0, 0.0, -9.8]) + self.count * 1e-3,
                          np.array([100.0 + self.compass[-1], 200.0, 300.0]))


def test_answers_that_came_back_late_are_left_out_and_every_reading_kept_is_placed_where_it_was_taken(monkeypatch):
    clock = SteppedClock(1000.0)
    monkeypatch.setattr(inav_dut, "time", clock)
    dut = InavDut(Product(backend="inav", connection="tcp:127.0.0.1:1"), InavOptions())
    link = dut.link = LateAnsweringLink(clock)
    stream = dut.samples(50.0)
    start = clock.now
    chunks = [next(stream) for _ in range(20)]
    accel_t = np.concatenate([c.imu.t_ms for c in chunks])
    accel_z = np.concatenate([c.imu.accel_mss[:, 2] for c in chunks])
    answer = np.rint((accel_z + 9.8) / 1e-3).astype(int) - 1  # which answer each accelerometer reading came in
    taken = (np.array(link.taken_at)[answer] - start) * 1000.0
    late = ((answer + 1) % 3 == 0) | ((answer + 1) % 5 == 0)
    assert len(accel_t) >= 40 and not late.any()  # no late answer's reading was used …
    # … and each one used is placed within half the lateness the backend accepts (the old stamps, at the
    # middle of every round trip, put the late ones 30 ms off)
    assert np.max(np.abs(accel_t - taken)) <= LATE_ANSWER_S / 2 * 1000.0
    mag_t = np.concatenate([c.t_ms for c in chunks])
    mags = np.concatenate([c.mag_ut for c in chunks])
    assert np.isin(mag_t, accel_t).all()  # a compass reading: the instant of the answer it first came in
    assert len(np.unique(mags, axis=0)) == len(mags)  # each compass reading once
    held = set(np.array(link.compass)[answer]) - {link.compass[0]}  # the stream's first: of unknown age
    assert len(mags) == len(held)  # every compass reading a timely answer carried is kept, none lost


class AlwaysLateLink(LateAnsweringLink):
    """After its first answer, every answer comes back late (a link whose least round trip was a lucky one)."""

    def imu(self) -> ImuReading:
        reading = super().imu()
        self.clock.now += LATE_S if self.count > 1 else 0.0
        return reading


def test_a_stream_whose_every_answer_is_late_still_hands_on_chunks_so_the_station_can_time_out(monkeypatch):
    clock = SteppedClock(1000.0)
    monkeypatch.setattr(inav_dut, "time", clock)
    dut = InavDut(Product(backend="inav", connection="tcp:127.0.0.1:1"), InavOptions())
    dut.link = AlwaysLateLink(clock)
    stream = dut.samples(50.0)
    chunks = [next(stream) for _ in range(5)]  # never blocks: each tenth of a second is handed on, empty
    assert sum(len(c.mag_ut) for c in chunks) == 0
    assert sum(len(c.imu.t_ms) for c in chunks if c.imu is not None) <= 1
    # a chunk without accelerometer readings carries none (a shapeless empty array broke whoever stacks them:
    # the conformance kit, under a loaded CI), and one with readings carries them as rows of three
    assert all(c.imu is None or c.imu.accel_mss.shape == (len(c.imu.t_ms), 3) for c in chunks)
    assert any(c.imu is None for c in chunks)
