"""Readings that are each the mean of the field over a window: taken back to the field at the window's middle.

Why: a firmware that publishes the mean of its driver's samples since its last read (ArduPilot's
``drain_accumulated_samples``, read every 100 ms) hands on, while the unit turns, the mean of a curving
vector: to second order ``m(t) + (W²/24)·m̈(t)``, the field at the window's middle plus a twenty-fourth of its
curvature over the window.  Turning at ω that is the field's part across the turn's axis shortened by
``(ωW)²/24`` — 0.04–0.09 % at a tumble's 60–80°/s, 1 % at 280°/s — and the direction tilted toward the axis.
The fit reads the shortfall as soft iron, and where the turn's rate goes with the direction (a spiral, a pose
cycle) as a shape: on ArduCopter's SITL every written matrix came out so, 3 to 6 of the σ the station stated.

The curvature is read from the readings themselves, two readings either side: the raw readings are an affine
image of the body's field (``S⁻¹·b + h``), so their curvature is the field's, and no calibration is needed to
take it off.  Two readings apart, the stencil adds 2 % to the noise (one reading apart: 8.5 %) and misses
``(2ωΔt)²/12`` of the curvature (under 1 % of the correction at 80°/s).  The window is the time between the
firmware's reads of the sensor, measured on the readings (:func:`read_period_s`); the samples in it come from
the driver's own rate, which the backend states.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

STENCIL = 2  # readings either side the curvature is read over


def window_mean_correction(raw_ut: NDArray, t_ms: NDArray, window_s: float, samples: int) -> NDArray:
    """What to add to each reading (rows, in time order; ``t_ms`` their stamps) to make the mean of ``samples``
    even samples over a window of ``window_s`` the field at its middle: ``−(W²/24)·(1 − 1/N²)·m̈`` (the spread
    of N samples' times; one sample is no mean), the curvature from the readings ``STENCIL`` before and after
    (at the ends, the nearest reading that has both)."""
    m = np.asarray(raw_ut, float)
    t_s = np.asarray(t_ms, float) / 1000.0
    n = len(m)
    if n < 2 * STENCIL + 1 or window_s <= 0 or samples <= 1:
        return np.zeros_like(m)
    centre = np.arange(STENCIL, n - STENCIL)
    before, after = centre - STENCIL, centre + STENCIL
    h_before = np.maximum(t_s[centre] - t_s[before], window_s)[:, None]  # shared stamps: a window apart
    h_after = np.maximum(t_s[after] - t_s[centre], window_s)[:, None]
    curvature = 2.0 * ((m[after] - m[centre]) / h_after - (m[centre] - m[before]) / h_before) / (h_before + h_after)
    curvature = np.concatenate([np.repeat(curvature[:1], STENCIL, axis=0), curvature,
                                np.repeat(curvature[-1:], STENCIL, axis=0)])
    return -(window_s**2 / 24.0) * (1.0 - 1.0 / samples**2) * curvature


def at_window_middles(raw_ut: NDArray, t_ms: NDArray, window_s: float, samples: int) -> NDArray:
    """``raw_ut`` (rows in any order) with each finite reading, a mean of ``samples`` over ``window_s``, taken
    back to the field at its window's middle."""
    m = np.array(raw_ut, dtype=float)
    t = np.asarray(t_ms, dtype=float)
    rows = np.flatnonzero(np.isfinite(m).all(axis=1) & np.isfinite(t))
    rows = rows[np.argsort(t[rows], kind="stable")]
    m[rows] += window_mean_correction(m[rows], t[rows], window_s, samples)
    return m


def read_period_s(t_ms: NDArray) -> float:
    """How often the firmware read the sensor (s), each reading averaging the time since the one before: the
    median time between distinct readings — a stream faster than the sensor's reads hands each read on once
    (the stream's repeats dropped), and a lost message then leaves one gap, not a longer window."""
    t = np.sort(np.asarray(t_ms, dtype=float)[np.isfinite(t_ms)])
    steps = np.diff(t)
    steps = steps[steps > 0]
    return float(np.median(steps)) / 1000.0 if len(steps) else 0.0


def samples_per_read(window_s: float, sample_hz: float) -> int:
    """How many of the driver's samples one reading averages: a driver sampling at 100 Hz read every 100 ms
    hands on means of 10; read as often as it samples, single samples (no window to undo)."""
    return max(1, round(window_s * sample_hz))
