"""A magnetometer's mounting proven against the unit's own accelerometer, and sensors against each other.

Why a package of its own: a compass mounted rotated (a GPS mast turned 90°, a board upside down, a
wrong orientation parameter) still traces a perfect ellipsoid — no fit residual exposes it; only
gravity, or another sensor, does.  ``orientations`` names the firmwares' discrete mountings,
``estimate`` finds the rotation from a sensor's axes to the body from accelerometer and calibrated
field pairs, ``agreement`` compares the heading two calibrated sensors give over the tumble.

Its names are imported on first use (:mod:`magline.core.lazy`).
"""

from __future__ import annotations

from magline.core.lazy import lazy_names

__all__, __getattr__, __dir__ = lazy_names(__name__, {
    "magline.core.mounting.agreement": ("HeadingAgreement", "heading_agreement"),
    "magline.core.mounting.estimate": ("ImuSeries", "MountingEstimate", "MountingUnobservable", "estimate_mounting"),
    "magline.core.mounting.orientations": (
        "ORIENTATIONS", "RIGHT_ANGLE", "nearest_right_angle", "orientation_matrix", "orientation_name",
    ),
})
