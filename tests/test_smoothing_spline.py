"""The mounting check's accelerometer spline is SciPy's smoothing spline, made faster: the same function."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import make_smoothing_spline

from magline.core.mounting.smoothing import SmoothingSpline


@pytest.mark.parametrize("readings", [5, 40, 2000])
@pytest.mark.parametrize("stiffness", [0.0, 0.1, 10.0])
def test_the_spline_is_scipys_smoothing_spline_at_its_readings_between_and_beyond_them(readings, stiffness):
    rng = np.random.default_rng(readings)
    t = 1.7e6 + np.cumsum(rng.uniform(4.0, 16.0, readings))  # a stream's stamps: uneven, far from zero
    angle = np.cumsum(rng.normal(0.0, 0.2, readings))
    accel = 9.81 * np.column_stack([np.sin(angle), np.cos(angle), 0.1 * angle]) + rng.normal(0.0, 0.3, (readings, 3))
    lam = stiffness * 10.0**3
    when = np.concatenate([t, rng.uniform(t[0] - 30.0, t[-1] + 30.0, 500)])
    ours = SmoothingSpline.fit(t, accel, lam)
    theirs = make_smoothing_spline(t, accel, lam=lam)
    assert np.max(np.abs(ours(when) - theirs(when))) < 1e-9 * 9.81
    one_axis = SmoothingSpline.fit(t, accel[:, 1], lam)(when)
    assert one_axis.shape == when.shape
    assert np.max(np.abs(one_axis - make_smoothing_spline(t, accel[:, 1], lam=lam)(when))) < 1e-9 * 9.81


def test_with_no_stiffness_the_spline_passes_through_every_reading_and_with_much_it_is_their_straight_line():
    t = np.array([0.0, 10.0, 25.0, 30.0, 50.0, 61.0])
    y = np.array([1.0, -2.0, 0.5, 3.0, -1.0, 2.0])
    assert SmoothingSpline.fit(t, y, 0.0)(t) == pytest.approx(y, abs=1e-12)
    line = np.polyfit(t, y, 1)
    assert SmoothingSpline.fit(t, y, 1e12)(t) == pytest.approx(np.polyval(line, t), abs=1e-6)


@pytest.mark.parametrize("t", [[0.0, 1.0], [0.0, 2.0, 2.0, 3.0], [0.0, 3.0, 1.0, 4.0]])
def test_too_few_readings_or_stamps_out_of_order_are_refused(t):
    with pytest.raises(ValueError, match="at least three readings at increasing instants"):
        SmoothingSpline.fit(np.array(t), np.zeros((len(t), 3)), 1.0)
