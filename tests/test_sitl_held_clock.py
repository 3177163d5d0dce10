"""The SITL peers' motion clock: it stands while the unit is held and goes on from there."""

from __future__ import annotations

import pytest

from magline.sitl.held_clock import HeldClock


def test_the_motion_clock_stands_through_each_hold_and_runs_on_from_where_it_stood():
    clock = HeldClock()
    assert clock.motion_s(10.0, 12.0, held=False) == 2.0
    assert clock.motion_s(10.0, 13.0, held=True) == 3.0  # the hold begins: the motion stops here
    assert clock.motion_s(10.0, 20.0, held=True) == 3.0
    assert clock.motion_s(10.0, 21.0, held=False) == 3.0  # released: 8 s stood, on from 3 s
    assert clock.motion_s(10.0, 22.5, held=False) == pytest.approx(4.5)
    clock.motion_s(10.0, 23.0, held=True)
    assert clock.motion_s(10.0, 30.0, held=False) == pytest.approx(5.0)  # two holds, 15 s stood in all
