"""Do two calibrated magnetometers give the unit the same heading?

Why at the station: both firmwares compare their compasses before arming (ArduPilot's "Compasses
inconsistent" allows tens of degrees), far too coarse to ship a unit whose GPS-mast compass and
board compass disagree by a few degrees — enough to make the estimator switch compasses in flight.
Here the heading is taken as the firmware will take it: each sensor's calibrated field in body axes,
projected onto the horizontal plane the accelerometer gives, the two paired by time.

What is judged is the *relation* between the two sensors, not their raw differences: sensor B's field
is fitted as a linear map of sensor A's over the whole tumble (``b ≈ M·a``, robustly: readings the map
does not explain are left out), and the headings ``a`` and ``M·a`` give at each of the tumble's
attitudes are compared — their median, largest and signed mean.  A mounting that differs (a rotation),
or a calibration that leaves one sensor stretched against the other, is a property of ``M`` and shows
at the attitudes where it matters; noise is averaged over every reading instead of taken at its worst.

Why not the differences themselves: the largest of a tumble's raw (or windowed) differences is an
extreme of noise.  Two good 10 Hz compasses on a short tumble crossed 3° that way (a false reject in
the false-reject benchmark, issue 28), and readings paired across a fast turn — one sensor read a few
milliseconds after the other, interpolated over 40° of rotation — differ by tens of degrees without
any fault.  A disagreement that is not linear in the field (a saturating sensor, a transient) is the
per-sensor fit's residual checks' to find.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from magline.core.mounting.estimate import ImuSeries


# Headings are compared where the field has a horizontal part to give one: at least this fraction of
# its length.  Why: a heading is the angle of the field's horizontal part, so near a vertical field a
# relation error of ε turns it by ε·|B|/|B_h|; a good pair on a tumble that rocks through such
# attitudes read 3.5° "apart" there.  The attitudes a drone flies in (tilt ≤ 45° at inclinations up to
# 60°) keep at least 0.25.
HORIZONTAL_MIN = 0.25
OUTLIER_FACTOR = 4.0  # a pair whose misfit exceeds this many times the median misfit is left out
REFITS = 3
TIMING_GRID = 8  # shifts looked at on each side of the paired timing before the refinement


@dataclass
class HeadingAgreement:
    median_deg: float  # median |heading difference| over the tumble's attitudes
    max_deg: float  # the largest of them
    mean_deg: float  # signed mean (a constant yaw offset between the sensors)
    pairs: int  # readings paired in time
    used: int = 0  # of them, the ones the relation was fitted to
    relation: NDArray | None = None  # ``M``: sensor B's field as a linear map of sensor A's
    timing_window_ms: float = 0.0  # how far B's relative timing was open (0: taken as paired)
    timing_shift_ms: float = 0.0  # the shift of B's stamps within the window the figures are taken at
    timing_deg: float = 0.0  # how much the median moved over the window: what timing alone can explain
    paired_median_deg: float | None = None  # the median at the paired timing itself (window open only)


def slerp_rows(t_new: NDArray, t: NDArray, values: NDArray) -> NDArray:
    """Vectors at ``t_new`` from readings at ``t``: direction along the great circle between the two
    readings around each time, length linearly in between; the ends are held.

    Why not linear: read every 0.1 s on a unit turning 500°/s, two readings are 50° apart, and the
    straight line between them is up to 10 % shorter than either (a stretch the relation would take
    for a disagreement) and off the arc in direction."""
    order = np.argsort(t)
    t, values = np.asarray(t, float)[order], np.asarray(values, float)[order]
    t_new = np.clip(np.asarray(t_new, float), t[0], t[-1])
    right = np.clip(np.searchsorted(t, t_new, side="right"), 1, len(t) - 1)
    left = right - 1
    span = t[right] - t[left]
    f = np.where(span > 0, (t_new - t[left]) / np.where(span > 0, span, 1.0), 0.0)[:, None]
    u, v = values[left], values[right]
    nu, nv = np.linalg.norm(u, axis=1, keepdims=True), np.linalg.norm(v, axis=1, keepdims=True)
    du, dv = u / np.maximum(nu, 1e-12), v / np.maximum(nv, 1e-12)
    angle = np.arccos(np.clip(np.einsum("ij,ij->i", du, dv), -1.0, 1.0))[:, None]
    sin = np.sin(angle)
    straight = sin < 1e-9
    wu = np.where(straight, 1.0 - f, np.sin((1.0 - f) * angle) / np.where(straight, 1.0, sin))
    wv = np.where(straight, f, np.sin(f * angle) / np.where(straight, 1.0, sin))
    direction = wu * du + wv * dv
    direction /= np.maximum(np.linalg.norm(direction, axis=1, keepdims=True), 1e-12)
    return direction * ((1.0 - f) * nu + f * nv)


def fit_relation(a: NDArray, b: NDArray) -> tuple[NDArray, NDArray]:
    """``M`` with ``b ≈ M·a`` (rows are readings), and which rows it was fitted to.

    Least squares with a pull towards ``M = I`` worth one reading (the sensors are assumed to agree
    where the tumble gives no evidence), refitted without the pairs it cannot explain."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    keep = np.ones(len(a), bool)
    weight = float(np.mean(np.einsum("ij,ij->i", a, a)))
    relation = np.eye(3)
    for _ in range(REFITS):
        ak, bk = a[keep], b[keep]
        relation = np.linalg.solve(ak.T @ ak + weight * np.eye(3), ak.T @ bk + weight * np.eye(3)).T
        misfit = np.linalg.norm(b - a @ relation.T, axis=1)
        new_keep = misfit <= OUTLIER_FACTOR * np.median(misfit[keep])
        if new_keep.sum() < 10 or np.array_equal(new_keep, keep):
            break
        keep = new_keep
    return relation, keep


def heading_difference_deg(a: NDArray, b: NDArray, up: NDArray) -> NDArray:
    """Signed heading of ``b`` against ``a`` (degrees, about ``up``), row by row."""
    ha = a - np.einsum("ij,ij->i", a, up)[:, None] * up
    hb = b - np.einsum("ij,ij->i", b, up)[:, None] * up
    return np.degrees(np.arctan2(np.einsum("ij,ij->i", up, np.cross(ha, hb)), np.einsum("ij,ij->i", ha, hb)))


def heading_agreement(body_a: NDArray, t_a_ms: NDArray, body_b: NDArray, t_b_ms: NDArray,
                      imu: ImuSeries, timing_window_ms: float = 0.0) -> HeadingAgreement | None:
    """Heading difference of sensor B against sensor A (body-axis calibrated fields on their own time
    stamps); None when the readings do not overlap in time.

    ``timing_window_ms``: how far B's stamps may still be off against A's (the station's uncertainty of
    their relative timing); the agreement is taken at the relative timing within it that agrees best.
    Why: a relative time shift turns one sensor against the other about the axis the unit turns about,
    and on a tumble that mostly turns one way it is indistinguishable from a turned sensor — 1 ms at
    1,400°/s read as 2.3° of disagreement.  Two compasses read by different driver loops reach their
    streams at different ages; that is not a defect of the unit, and the station measures it only to
    its own σ.  The window is the price: a real disagreement smaller than what the window's shift
    explains cannot be told from timing on that tumble (``timing_deg`` says how much that is)."""
    t_a = np.asarray(t_a_ms, float)
    t_b = np.asarray(t_b_ms, float)
    lo = max(np.min(t_b) + timing_window_ms, np.min(imu.t_ms))
    hi = min(np.max(t_b) - timing_window_ms, np.max(imu.t_ms))
    inside = (t_a >= lo) & (t_a <= hi)
    if inside.sum() < 10:
        return None
    up, usable = imu.gravity_track().at(t_a)
    inside &= usable  # gravity known there: not in a gap of the stream, the unit not accelerated
    if inside.sum() < 10:
        return None
    t = t_a[inside]
    a = np.asarray(body_a, float)[inside]
    up = up[inside] / np.linalg.norm(up[inside], axis=1, keepdims=True)
    vertical = np.einsum("ij,ij->i", a, up)
    horizontal = np.sqrt(np.maximum(np.einsum("ij,ij->i", a, a) - vertical**2, 0.0)) / np.linalg.norm(a, axis=1)
    headed = horizontal >= HORIZONTAL_MIN
    if headed.sum() < 10:
        return None

    def at_shift(shift_ms: float) -> HeadingAgreement:
        relation, used = fit_relation(a, slerp_rows(t, t_b + shift_ms, body_b))
        diff = heading_difference_deg(a[headed], a[headed] @ relation.T, up[headed])
        return HeadingAgreement(median_deg=float(np.median(np.abs(diff))), max_deg=float(np.max(np.abs(diff))),
                                mean_deg=float(np.mean(diff)), pairs=len(diff), used=int(used.sum()),
                                relation=relation, timing_window_ms=timing_window_ms, timing_shift_ms=shift_ms)

    paired = at_shift(0.0)
    if timing_window_ms <= 0.0:
        return paired
    from scipy.optimize import minimize_scalar  # on use: scipy costs every command start

    grid = np.linspace(-timing_window_ms, timing_window_ms, 2 * TIMING_GRID + 1)
    medians = [at_shift(float(shift)).median_deg for shift in grid]
    k = int(np.argmin(medians))
    bounds = (float(grid[max(k - 1, 0)]), float(grid[min(k + 1, len(grid) - 1)]))
    found = minimize_scalar(lambda shift: at_shift(float(shift)).median_deg, bounds=bounds, method="bounded",
                            options={"xatol": timing_window_ms * 1e-3})
    best = min((at_shift(float(found.x)), at_shift(float(grid[k]))), key=lambda agreement: agreement.median_deg)
    best.timing_deg = float(max(medians) - best.median_deg)
    best.paired_median_deg = paired.median_deg
    return best
