"""The unit-level checks of the validate phase: every magnetometer's mounting against the unit's own
accelerometer, and every pair of magnetometers against each other (hook ``magline_validate_unit``,
registered like any plugin through the ``mounting`` entry point, whose module :mod:`.hooks` imports
this one on the first unit).

What is judged, per sensor (names prefixed ``mag2.`` … for sensors after the primary):
- ``orientation``: the firmware orientation value the sensor is really mounted in; another value than
  the one configured FAILs, naming the parameter value that would fix it — or, with the product's
  ``orientation: fix``, leaves it in ``run.orientation_fixes`` for the persist phase;
- ``mounting_error_deg``: what is left between the sensor's axes and that orientation (or the custom
  rotation the firmware already holds); with the product's ``misalignment: write`` the whole measured
  rotation is also left in ``run.rotation_writes`` where the backend can hold it
  (``rotation_params``: PX4's custom Euler angles), the note saying so or why not — the limit still
  judges the mechanical misalignment;
- ``inclination_error_deg``: the field's inclination the unit saw against the field source's;
- ``time_skew_ms`` (and its σ): when the sensor's readings were taken against their messages' stamps, on
  the accelerometer's clock — found from the tumble with the mounting (:mod:`magline.core.mounting.skew`),
  recorded as a station figure, and used to pair the sensors' readings for their heading agreement;
and per pair ``heading_agreement_median_deg`` / ``_max_deg`` (names ``mag1-mag2.…``), the headings
taken as the firmware will take them once each sensor's orientation is right (a wrong orientation is
its own failure, not a second one of every pair).

A coil's affine fit measures a sensor's axes against the coil itself (``misalignment_deg``): there
gravity never turns, and the coil's proof stands instead.  No accelerometer: the station cannot prove
the mounting — a :class:`~magline.core.faults.StationFault` (ERROR) unless the product opted out.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
from numpy.typing import NDArray

from magline.core.dut import DutError, ParamValue, WritesOrientation, WritesRotation
from magline.core.faults import StationFault
from magline.core.measurements import Json, Measurement, Numeric, Verdict
from magline.core.mounting.agreement import heading_agreement
from magline.core.mounting.estimate import MountingEstimate, MountingUnobservable, estimate_mounting
from magline.core.mounting.line_skew import OWN_SKEW_DETERMINED_MS, skew_prior
from magline.core.mounting.orientations import (
    nearest_right_angle,
    orientation_matrix,
    orientation_name,
    rotation_angle_deg,
)

if TYPE_CHECKING:
    from magline.core.dut import Magnetometer
    from magline.core.fit import FitResult
    from magline.core.mounting.agreement import HeadingAgreement
    from magline.core.sequencer.context import RunContext

# Two sensors' skews are taken as one unless their estimates differ by more than this many σ of the
# difference; a pair paired at two skews keeps the same many σ open in its heading agreement (the
# difference it was paired at is known only that well).
TIMING_WINDOW_SIGMAS = 3.0


def calibrated(fit: FitResult, raw_ut: NDArray, t_ms: NDArray) -> NDArray:
    """``S·(m_raw − h)`` for every row, each reading first taken back to its window's middle where the fit
    took its readings so (a reading averaged while the unit turned is tilted toward the turn's axis)."""
    raw = np.asarray(raw_ut, float)
    if fit.reading_window is not None:
        from magline.core.fit.reading_window import at_window_middles

        raw = at_window_middles(raw, t_ms, float(fit.reading_window["window_s"]), int(fit.reading_window["samples"]))
    return (raw - fit.hard_iron_ut) @ np.asarray(fit.soft_iron).T


def applied_rotation(sensor: Magnetometer) -> NDArray:
    """The rotation the firmware applied to the streamed readings already (ArduPilot: its orientation)."""
    return orientation_matrix(sensor.orientation) if sensor.readings_rotated else np.eye(3)


def configured_rotation(sensor: Magnetometer) -> NDArray:
    """The rotation the firmware applies to this sensor now: its custom one, else its orientation's."""
    return np.asarray(sensor.rotation, float) if sensor.rotation is not None else orientation_matrix(sensor.orientation)


def fix_text(run: RunContext, sensor: Magnetometer, value: int) -> str:
    if not isinstance(run.dut, WritesOrientation) or not sensor.fix_params:
        return "no parameter of this firmware can hold it: remount the sensor"
    params = run.dut.orientation_params(sensor.device_id, value)
    return "set " + ", ".join(f"{k} = {v}" for k, v in params.items())


class JudgedMounting(NamedTuple):
    """A sensor's estimated mounting as the check reads it: the firmware orientation it is really in
    (``found``), whether that is the configured one (``right``), and the angle left between its axes and
    what the firmware will apply (``error_deg``, judged by ``mounting_error_deg``)."""

    found: int
    expected: int
    right: bool
    error_deg: float
    mounted: NDArray  # sensor axes → body, as the unit really is


def judge_mounting(sensor: Magnetometer, estimate: MountingEstimate) -> JudgedMounting:
    """What the check makes of ``estimate`` for ``sensor`` — shared with the tumble's stop, which asks
    whether that verdict is decided before the tumble may end (``core/acquisition/tumble_stop.py``)."""
    mounted = estimate.data_to_body @ applied_rotation(sensor)
    found, error_deg = estimate.right_angle_of(mounted)
    configured = configured_rotation(sensor)
    expected = sensor.orientation if sensor.rotation is None else nearest_right_angle(configured)[0]
    right = rotation_angle_deg(orientation_matrix(found), orientation_matrix(expected)) < 1e-6
    if sensor.rotation is not None:
        # a custom rotation is right when it explains the mounting at least as well as the nearest right
        # angle does: one half-way between two right angles (INAV's align_mag_yaw = 45°) had its nearest
        # right angle decided by noise, and a unit mounted exactly as configured FAILed 1 run in 4
        right = rotation_angle_deg(mounted, configured) <= rotation_angle_deg(mounted, orientation_matrix(found))
        if right:  # a custom rotation held already: what it leaves
            error_deg = rotation_angle_deg(mounted, configured)
    return JudgedMounting(found=found, expected=expected, right=right, error_deg=error_deg, mounted=mounted)


def validate_unit(run: RunContext, fits: dict[int, FitResult]) -> list[Measurement]:
    """Every magnetometer's mounting and every pair's heading agreement (``magline_validate_unit``)."""
    setting = run.product.orientation
    if setting == "skip":
        run.record.unit_info["mounting"] = "not proven: the product says orientation: skip"
        run.log("mounting not proven (orientation: skip)")
        return []
    if any(f.model == "affine" for f in fits.values()):
        run.record.unit_info["mounting"] = "proven by the coil: misalignment_deg from the affine fit"
        return []
    attempt = run.attempts[-1]
    limits = run.limits
    reference = getattr(run.field_source, "reference_inclination_deg", lambda: None)()
    out: list[Measurement] = []
    bodies: dict[int, tuple[NDArray, NDArray, MountingEstimate]] = {}
    report: dict[str, dict] = {}
    fixes: dict[int, int] = {}
    rotations: dict[int, HeldRotation] = {}
    for position, sensor in enumerate(run.magnetometers):
        samples = attempt.samples if position == 0 else attempt.more[sensor.device_id]
        label = run.sensor_label(sensor.device_id)
        prefix = run.sensor_prefix(sensor.device_id)
        cal = calibrated(fits[sensor.device_id], samples.mag_ut, samples.t_ms)
        try:
            estimate = estimate_mounting(cal, samples.t_ms, attempt.imu, dip_deg=reference,
                                         skew_prior=skew_prior(run, prefix))
        except MountingUnobservable as exc:
            raise StationFault(f"the mounting of {label} cannot be proven: {exc} (a product without an "
                               "accelerometer in its stream may say orientation: skip)") from None
        applied = applied_rotation(sensor)
        found, expected, right, error_deg, mounted = judge_mounting(sensor, estimate)
        final = orientation_matrix(found)  # the agreement is judged as the sensor will be held once right
        if right and sensor.rotation is not None:  # a custom rotation held already: what it leaves
            final = configured_rotation(sensor)
        note = ""
        verdict = Verdict.PASS
        if not right:
            where = (f"{label} is mounted {orientation_name(found)} (orientation {found}), configured "
                     f"{orientation_name(expected)} ({sensor.orientation})")
            if setting == "fix" and sensor.fix_params:
                fixes[sensor.device_id] = found
                note = f"{where}: {fix_text(run, sensor, found)} — written with the calibration"
                run.log(note)
            else:
                verdict = Verdict.FAIL
                note = f"{where}: {fix_text(run, sensor, found)}"
        out.append(Numeric(name=prefix + "orientation", value=float(found),
                           low=float(found if fixes.get(sensor.device_id) is not None else expected),
                           high=float(found if fixes.get(sensor.device_id) is not None else expected),
                           verdict=verdict, note=note))
        held = _hold_misalignment(run, sensor, mounted, error_deg) if run.product.misalignment == "write" else None
        if held is not None and held.params:
            rotations[sensor.device_id] = held
            final = mounted  # the firmware will hold the whole rotation: the pairs are judged so
        out.append(replace(Numeric.of(prefix + "mounting_error_deg", error_deg, limits),
                           note=held.note if held is not None else ""))
        out.append(Numeric.of(prefix + "mounting_sigma_deg", estimate.sigma_deg, limits))
        out.append(Numeric.of(prefix + "inclination_deg", estimate.inclination_deg, limits))
        out.append(_skew_judged(Numeric.of(prefix + "time_skew_ms", estimate.skew_ms, limits), estimate, label))
        out.append(Numeric.of(prefix + "time_skew_sigma_ms", estimate.skew_sigma_ms, limits))
        if estimate.own_skew_sigma_ms <= OWN_SKEW_DETERMINED_MS:  # what the line learns its skew from
            out.append(Numeric.of(prefix + "time_skew_own_ms", estimate.own_skew_ms, limits))
            out.append(Numeric.of(prefix + "time_skew_own_sigma_ms", estimate.own_skew_sigma_ms, limits))
        if reference is not None:
            out.append(Numeric.of(prefix + "inclination_error_deg", estimate.inclination_deg - reference, limits))
        bodies[sensor.device_id] = (cal @ (final @ applied.T).T, np.asarray(samples.t_ms, float), estimate)
        report[prefix.rstrip(".") or "mag1"] = {"device_id": sensor.device_id, "found": found,
                                                "configured": sensor.orientation, **estimate.to_dict()}
        if held is not None:
            report[prefix.rstrip(".") or "mag1"]["misalignment_written"] = held.params or held.note
    for a, b in itertools.combinations(run.magnetometers, 2):
        (body_a, t_a, est_a), (body_b, t_b, est_b) = bodies[a.device_id], bodies[b.device_id]
        skew_a, skew_b = paired_skews(est_a, est_b)
        window = 0.0 if skew_a == skew_b else TIMING_WINDOW_SIGMAS * float(np.hypot(est_a.skew_sigma_ms,
                                                                                     est_b.skew_sigma_ms))
        agreement = heading_agreement(body_a, t_a + skew_a, body_b, t_b + skew_b, attempt.imu, window)
        if agreement is None:
            raise StationFault(f"{run.sensor_label(a.device_id)} and {run.sensor_label(b.device_id)} have no "
                               "readings at the same time to compare")
        pair = f"{_tag(run, a)}-{_tag(run, b)}."
        for figure, value in (("median", agreement.median_deg), ("max", agreement.max_deg)):
            out.append(_timing_limited(Numeric.of(f"{pair}heading_agreement_{figure}_deg", value, limits),
                                       agreement, run.sensor_label(a.device_id), run.sensor_label(b.device_id)))
        report[pair.rstrip(".")] = {"median_deg": agreement.median_deg, "max_deg": agreement.max_deg,
                                    "mean_deg": agreement.mean_deg, "pairs": agreement.pairs, "used": agreement.used,
                                    "timing_window_ms": agreement.timing_window_ms,
                                    "timing_shift_ms": agreement.timing_shift_ms, "timing_deg": agreement.timing_deg,
                                    "relation": np.round(agreement.relation, 6).tolist()}
    run.orientation_fixes = fixes
    run.rotation_writes = {d: r.params for d, r in rotations.items()}
    run.record.unit_info["mounting"] = report
    out.append(Json(name="mounting", data=report))
    return out


# Beyond this many σ of the two together, a unit's own skew is not the line's: REVIEW, said in words.
SKEW_DISAGREEMENT_SIGMAS = 3.0


def _skew_judged(figure: Numeric, estimate: MountingEstimate, label: str) -> Numeric:
    """The skew's figure flagged for review where the unit's own tumble puts its skew off the line's.
    Why REVIEW and not FAIL: the mounting was judged with the line's skew and the unit may be good; but
    a unit timed unlike the line's (another firmware build, a link that delays one message and not the
    other) is one whose mounting verdict rests on a prior that may not be its own."""
    if estimate.prior is None or estimate.skew_disagreement <= SKEW_DISAGREEMENT_SIGMAS:
        return figure
    if figure.verdict is Verdict.FAIL:
        return figure
    return replace(figure, verdict=Verdict.REVIEW, note=(
        f"{label}'s own tumble puts its time skew at {estimate.own_skew_ms:.1f} ± {estimate.own_skew_sigma_ms:.1f} "
        f"ms, {estimate.skew_disagreement:.1f}σ off the line's {estimate.prior.describe()}: its readings are not "
        "timed as the line's units are (another firmware build, or a link that delays the compass), and its "
        "mounting was judged with the line's skew"))


def _timing_limited(figure: Numeric, agreement: HeadingAgreement, label_a: str, label_b: str) -> Numeric:
    """A pair's agreement figure flagged for review where it passes only because the two sensors'
    relative timing is uncertain: a disagreement as large as what that uncertainty alone explains
    (``timing_deg``) would have read the same, so the pass is not proven to the limit.  Why REVIEW and
    not ERROR: the unit is consistent with a good one and the doubt is the station's, said in the note."""
    if figure.verdict is not Verdict.PASS or figure.high is None or agreement.timing_deg <= 0.0:
        return figure
    if figure.value + agreement.timing_deg <= figure.high:
        return figure
    return replace(figure, verdict=Verdict.REVIEW, note=(
        f"the relative timing of {label_a} and {label_b} is known to ±{agreement.timing_window_ms:.1f} ms, and on "
        f"this tumble that alone explains up to {agreement.timing_deg:.1f}° of disagreement: the pass is not "
        "proven to the limit (more readings narrow it)"))


def paired_skews(a: MountingEstimate, b: MountingEstimate) -> tuple[float, float]:
    """The skews two sensors' readings are paired with: each its own where they differ beyond 3σ, else
    one common skew (their inverse-variance mean).  Why: on a fast tumble a few tenths of a
    millisecond between two estimates of one and the same skew turn one sensor against the other by
    half a degree; sensors read by the same driver cycle share their skew, and a difference the
    tumble cannot show is taken as none."""
    wa, wb = 1.0 / max(a.skew_sigma_ms, 1e-6) ** 2, 1.0 / max(b.skew_sigma_ms, 1e-6) ** 2
    if abs(a.skew_ms - b.skew_ms) > TIMING_WINDOW_SIGMAS * np.hypot(a.skew_sigma_ms, b.skew_sigma_ms):
        return a.skew_ms, b.skew_ms
    common = (wa * a.skew_ms + wb * b.skew_ms) / (wa + wb)
    return common, common


@dataclass(frozen=True)
class HeldRotation:
    """A sensor's whole mounting (right angle and misalignment) as the parameters that hold it."""

    params: dict[str, ParamValue]  # empty: the sensor cannot hold one (``note`` says why)
    note: str


def _hold_misalignment(run: RunContext, sensor: Magnetometer, mounted: NDArray, error_deg: float) -> HeldRotation:
    """``misalignment: write``: the backend's parameters for the measured rotation, or why it has none
    (logged and kept in the note: the discrete orientation stays what the firmware applies)."""
    label = run.sensor_label(sensor.device_id)
    try:
        if not isinstance(run.dut, WritesRotation):
            raise DutError("this backend cannot write a custom rotation")
        params = dict(run.dut.rotation_params(sensor.device_id, mounted))
    except DutError as exc:
        note = f"{label}: misalignment of {error_deg:.2f}° not written: {exc}"
        run.log(note)
        return HeldRotation({}, note)
    note = (f"{label}: misalignment of {error_deg:.2f}° written as a custom rotation ("
            + ", ".join(f"{k} = {v:.2f}" if isinstance(v, float) else f"{k} = {v}" for k, v in params.items()) + ")")
    run.log(note)
    return HeldRotation(params, note)


def _tag(run: RunContext, sensor: Magnetometer) -> str:
    return run.sensor_prefix(sensor.device_id).rstrip(".") or "mag1"
