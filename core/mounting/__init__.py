"""A magnetometer's mounting proven against the unit's own accelerometer, and sensors against each other.

Why a package of its own: a compass mounted rotated (a GPS mast turned 90°, a board upside down, a
wrong orientation parameter) still traces a perfect ellipsoid — no fit residual exposes it; only
gravity, or another sensor, does.  ``orientations`` names the firmwares' discrete mountings,
``estimate`` finds the rotation from a sensor's axes to the body from accelerometer and calibrated
field pairs, ``agreement`` compares the heading two calibrated sensors give over the tumble.
"""

from magline.core.mounting.agreement import HeadingAgreement, heading_agreement
from magline.core.mounting.estimate import ImuSeries, MountingEstimate, MountingUnobservable, estimate_mounting
from magline.core.mounting.orientations import (
    ORIENTATIONS,
    RIGHT_ANGLE,
    nearest_right_angle,
    orientation_matrix,
    orientation_name,
)

__all__ = ["ORIENTATIONS", "RIGHT_ANGLE", "HeadingAgreement", "ImuSeries", "MountingEstimate",
           "MountingUnobservable", "estimate_mounting", "heading_agreement", "nearest_right_angle",
           "orientation_matrix", "orientation_name"]
