"""Synthetic magnetometer data with known truth.

Why in core: the mock DUT, the tests and the benchmarks must all draw from the same sensor model
and the same operator motions, so that "accuracy against known synthetic truth" means one thing.
"""

from magline.core.synthetic.motions import MOTIONS, motion_directions
from magline.core.synthetic.sensor import SensorTruth, earth_field_ned, random_truth

__all__ = ["MOTIONS", "SensorTruth", "earth_field_ned", "motion_directions", "random_truth"]
