"""Synthetic magnetometer data with known truth.

Why in core: the mock DUT, the tests and the benchmarks must all draw from the same sensor model
and the same operator motions, so that "accuracy against known synthetic truth" means one thing.
"""

from magline.sim.truth.motions import MOTIONS, motion_directions
from magline.sim.truth.sensor import GRAVITY_MSS, SensorTruth, earth_field_ned, gravity_body, random_truth

__all__ = ["GRAVITY_MSS", "MOTIONS", "SensorTruth", "earth_field_ned", "gravity_body", "motion_directions",
           "random_truth"]
