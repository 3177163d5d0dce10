"""``acquisition.warm_up_s``: the tumble waits for the unit's own uptime, not for a fixed sleep.

The wait is driven here by a fake clock that the fake sleep advances, so each case says exactly how
long was waited; the simulated ArduPilot's warm-up row of the fault table
(``tests/test_station_faults.py``, ``warm-up-waited``) runs the same wait on real sockets.
"""

from __future__ import annotations

import pytest

from magline.core.faults import UnitAborted
from magline.core.sequencer.warm_up import STEP_S, wait_until_warm


class FakeUnit:
    """A unit whose uptime runs with the fake clock; ``reboot_at`` restarts it once at that clock time."""

    def __init__(self, up_s: float | None, reboot_at: float | None = None) -> None:
        self.clock = 0.0
        self.up_at_zero = up_s
        self.reboot_at = reboot_at
        self.asked = 0
        self.prompts: list[float] = []

    def uptime(self) -> float | None:
        self.asked += 1
        if self.up_at_zero is None:
            return None
        if self.reboot_at is not None and self.clock >= self.reboot_at:
            return self.clock - self.reboot_at
        return self.up_at_zero + self.clock

    def sleep(self, seconds: float) -> None:
        assert 0 < seconds <= STEP_S  # short steps: the operator's abort is looked at between them
        self.clock += seconds

    def wait(self, need_s: float, check_abort=lambda: None):
        return wait_until_warm(need_s, self.uptime, self.prompts.append, check_abort, self.sleep, lambda: self.clock)


def test_a_unit_that_has_run_long_enough_starts_at_once():
    unit = FakeUnit(up_s=30.0)
    warm = unit.wait(20.0)
    assert (warm.uptime_s, warm.waited_s, unit.prompts, unit.clock) == (30.0, 0.0, [], 0.0)
    assert "warm: up 30.0 s" in warm.words(20.0)


def test_a_unit_just_powered_waits_the_rest_of_its_warm_up_and_the_operator_is_told_once():
    unit = FakeUnit(up_s=3.0)
    warm = unit.wait(20.0)
    assert unit.clock == pytest.approx(17.0)  # the rest, by the unit's clock
    assert warm.waited_s == pytest.approx(17.0) and warm.uptime_s == 3.0
    assert unit.prompts == [pytest.approx(17.0)]
    assert unit.asked == 2  # asked again when due: the unit's clock decides, not the station's
    assert "waited 17.0 s" in warm.words(20.0)


def test_a_unit_that_rebooted_meanwhile_is_waited_for_by_its_new_clock():
    unit = FakeUnit(up_s=15.0, reboot_at=2.0)  # due at 5 s by the first answer; then up only 3 s
    unit.wait(20.0)
    assert unit.clock == pytest.approx(22.0)  # 5 s, then the 17 s its new boot still lacks


def test_a_unit_that_does_not_say_its_uptime_gets_the_whole_warm_up_from_now():
    unit = FakeUnit(up_s=None)
    warm = unit.wait(12.0)
    assert unit.clock == pytest.approx(12.0) and warm.uptime_s is None
    assert unit.prompts == [pytest.approx(12.0)]
    assert "its uptime unknown" in warm.words(12.0)


def test_the_operator_can_stop_the_unit_during_the_wait():
    unit = FakeUnit(up_s=0.0)

    def abort_after_a_second():
        if unit.clock >= 1.0:
            raise UnitAborted("stopped by Ctrl-C")

    with pytest.raises(UnitAborted):
        unit.wait(60.0, abort_after_a_second)
    assert unit.clock == pytest.approx(1.0)
