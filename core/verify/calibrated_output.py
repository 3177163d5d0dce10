"""The proof on the firmware's own terms: after the power cycle, the unit's *calibrated* output.

Why: a read-back only proves that what was written is stored; a calibration written to a slot the
firmware does not apply to this sensor, or with a wrong sign or unit, is stored just as well.

Where the backend reads the firmware's raw and calibrated output side by side
(``raw_and_calibrated_ut(count)``, PX4), two things are proven.  First, that the firmware
applies magline's calibration: its calibrated vectors equal magline's calibration applied to the same
raw readings and turned into the body as the firmware turns them, within what noise and the int16
quantisation leave — a wrong sign, unit, slot, or a
calibration not applied is far outside that, whatever the fit's quality.  With several compasses the
firmware's output is the one its voter selected, which MAVLink does not name: it must be magline's
calibration of one of them.  Second, that the sensor is where the tumble left it: the magnitude
against the reference, within the station's ``field_tolerance_pct`` widened by the fit's own radial σ
in the direction read (where no raw stream is read, the raw readings behind the output are magline's
calibration undone) — a unit resting where the tumble saw little is known less well there, and a good
one FAILed at −3.1 % in such a direction; an offset that moved since the tumble still reads off.
Elsewhere (``calibrated_field_ut(count)`` / ``calibrated_fields_ut(count, device_ids)``) the magnitude is
held to that widened tolerance alone.  Field sources whose reference is the field the unit sits in say
``reference_is_ambient = True`` (a coil's generated field is gone after its schedule).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from magline.core.dut import CalibratedBesideRaw, ReadsCalibratedField, ReadsCalibratedFields, ReadsRawAndCalibrated

if TYPE_CHECKING:
    from magline.core.fit import FitResult
    from magline.core.sequencer.context import RunContext

# Beside the raw readings: the spread of their difference sets the tolerance (from 19 degrees of freedom).
CALIBRATED_READINGS = 20
# The magnitude alone: its median is held to the station's field tolerance (3 % of 48 µT by default: 1.44 µT),
# against which the median of ten readings of a 0.3 µT-noisy compass (0.12 µT) is as good as of twenty
# (0.08 µT) — and a second less of a 10 Hz compass (ArduPilot, INAV) at rest after its power cycle
MAGNITUDE_READINGS = 10
# How far a right result may be from what it is held to, in units of its own σ: 4.5σ is crossed by a
# normal figure with probability 7e-6 — a good unit is not failed by the check's own noise.
PROOF_Z = 4.5
# The largest error undoing the firmwares' int16 milligauss truncation leaves in a magnitude: half a
# milligauss on each axis (0.05 µT), √3 of it on a vector.
QUANTUM_UT = 0.05 * 3**0.5
NOT_MAGLINES = "is not magline's calibration of the same raw readings"


@dataclass(frozen=True)
class Applied:
    """The firmware's calibrated vectors against magline's calibration of the same raw readings,
    turned into the body as the firmware turns them."""

    difference_ut: float  # |mean of firmware − magline's|, a vector's length
    tolerance_ut: float  # from the noise of the difference and the quantisation
    firmware_ut: float  # median magnitudes, for the words
    expected_ut: float

    @property
    def holds(self) -> bool:
        return self.difference_ut <= self.tolerance_ut


def applied(fit: FitResult, raw_ut: np.ndarray, to_body: np.ndarray, firmware_ut: np.ndarray,
            estimated_bias_ut: float = 0.0) -> Applied:
    """Compare the firmware's calibrated vectors with magline's calibration of ``raw_ut`` turned by
    ``to_body``.  Vectors, not magnitudes: a wrong sign of an offset perpendicular to the field where
    the unit rests leaves the magnitude as it should be (1 of 20 such units passed a magnitude proof).
    ``estimated_bias_ut``: how far the firmware's own bias estimate may have moved its output, allowed
    beside the noise."""
    expected = fit.apply(raw_ut) @ np.asarray(to_body, float).T
    difference = np.atleast_2d(firmware_ut) - expected
    mean = difference.mean(axis=0)
    spread = difference.std(axis=0, ddof=1) / np.sqrt(len(difference)) if len(difference) > 1 else np.zeros(3)
    return Applied(float(np.linalg.norm(mean)),
                   PROOF_Z * float(np.linalg.norm(spread)) + QUANTUM_UT + estimated_bias_ut,
                   float(np.median(np.linalg.norm(np.atleast_2d(firmware_ut), axis=1))),
                   float(np.median(np.linalg.norm(expected, axis=1))))


def estimated_bias_allowance_ut(read: CalibratedBesideRaw, field_tolerance_pct: float, reference_ut: float) -> float:
    """What the firmware's online bias estimate may have taken from its calibrated output by the time it is
    read (0 where the output is not less an estimate).  PX4's HIGHRES_IMU is the calibration's output less
    EKF2's magnetometer bias, which learns from the boot on the field's difference to the firmware's model of
    it (World Magnetic Model): 0.48 µT within two seconds on PX4 SITL, a unit at rest in a field 1–2 µT from
    the model's.  A station accepts the field it calibrates in within its ``field_tolerance_pct`` of the
    reference, so an estimate up to that is a good unit's; a calibration applied with a wrong sign, unit or
    slot moves the output by the unit's offset or its field, tens of µT."""
    return field_tolerance_pct / 100.0 * reference_ut if read.less_estimated_bias else 0.0


def calibrated_output_problems(run: RunContext, dut: object, figures: dict) -> list[str]:
    """Why the unit's calibrated output after the power cycle is not magline's calibration applied
    where the tumble left the sensor (empty when it is, or when nothing can be read); the figures
    read go into ``figures``."""
    reference = run.reference_field_ut
    if not isinstance(dut, ReadsCalibratedField) or not reference or not getattr(run.field_source,
                                                                                  "reference_is_ambient", False):
        return []
    both = dut.raw_and_calibrated_ut(CALIBRATED_READINGS) if isinstance(dut, ReadsRawAndCalibrated) else None
    if both is not None:
        return _paired_proof(run, both, figures)
    return _magnitude_proof(run, dut, figures)


def _paired_proof(run: RunContext, read: CalibratedBesideRaw, figures: dict) -> list[str]:
    """The firmware's calibrated output beside the raw readings of every compass it may come from:
    it must be magline's calibration of one of them, and that one's magnitude meets the reference."""
    several = len(run.magnetometers) > 1
    raws = read.raw_ut
    magnitudes = np.linalg.norm(np.atleast_2d(read.calibrated_ut), axis=1)
    allowance = estimated_bias_allowance_ut(read, run.station.verify.field_tolerance_pct,
                                            float(run.reference_field_ut or 0.0))
    found = {d: applied(run.fits[d], raw, read.to_body[d], read.calibrated_ut, allowance) for d, raw in raws.items()
             if d in run.fits}
    if not found:
        return []
    matched = [d for d, a in found.items() if a.holds]
    device_id = matched[0] if matched else min(found, key=lambda d: found[d].difference_ut / found[d].tolerance_ut)
    prefix = run.sensor_prefix(device_id).replace(".", "_") if several else ""
    result = found[device_id]
    figures[f"{prefix}applied_difference_ut"] = result.difference_ut
    figures[f"{prefix}applied_tolerance_ut"] = result.tolerance_ut
    if not matched:
        whose = (f" of any of its compasses (closest: {run.sensor_label(device_id)})" if several else "")
        estimate = f" and the firmware's estimate of its bias (up to {allowance:.2f} µT)" if allowance else ""
        return [f"the firmware's calibrated output {NOT_MAGLINES}{whose}: it reads {result.firmware_ut:.2f} µT where "
                f"the calibration written gives {result.expected_ut:.2f} µT (the vectors {result.difference_ut:.2f} µT "
                f"apart, tolerance {result.tolerance_ut:.2f} µT from noise and quantisation{estimate}) — a wrong "
                "sign, unit or slot, or the calibration not applied"]
    whose = f"{run.sensor_label(device_id)} (the compass the firmware selects): " if several else ""
    problem = _magnitude_problem(run, run.fits[device_id], raws[device_id], float(np.median(magnitudes)),
                                 prefix, figures)
    return [whose + problem] if problem else []


def _magnitude_proof(run: RunContext, dut: ReadsCalibratedField, figures: dict) -> list[str]:
    """Without raw readings beside the calibrated ones: each compass's calibrated magnitude against the
    reference, the raw behind it taken as magline's calibration undone."""
    from magline.core.mounting.checks import configured_rotation  # on use: every command loads this plugin

    several = len(run.magnetometers) > 1
    at_once = several and isinstance(dut, ReadsCalibratedFields)
    read_all = dut.calibrated_fields_ut(MAGNITUDE_READINGS, [m.device_id for m in run.magnetometers]) \
        if at_once else {}
    problems = []
    for sensor in run.magnetometers if several else run.magnetometers[:1] or [None]:
        if at_once:
            readings = read_all.get(sensor.device_id)
        else:
            readings = (dut.calibrated_field_ut(MAGNITUDE_READINGS, sensor=sensor.device_id) if several
                        else dut.calibrated_field_ut(MAGNITUDE_READINGS))
        if readings is None or len(readings) == 0:
            continue
        whose = f"{run.sensor_label(sensor.device_id)}: " if several else ""
        prefix = run.sensor_prefix(sensor.device_id).replace(".", "_") if sensor is not None else ""
        fit = run.fits.get(sensor.device_id) if sensor is not None else None
        measured = float(np.median(np.linalg.norm(np.atleast_2d(readings), axis=1)))
        raw = None
        if fit is not None:
            frame = np.eye(3) if sensor is None or sensor.readings_rotated else configured_rotation(sensor)
            raw = np.linalg.solve(fit.soft_iron, (np.atleast_2d(readings) @ frame).T).T + fit.hard_iron_ut
        problem = _magnitude_problem(run, fit, raw, measured, prefix, figures)
        if problem:
            problems.append(whose + problem)
    return problems


def _magnitude_problem(run: RunContext, fit: FitResult | None, raw: np.ndarray | None, measured: float,
                       prefix: str, figures: dict) -> str:
    """The calibrated magnitude ``measured`` against the reference, within ``field_tolerance_pct``
    widened by ``PROOF_Z`` × the fit's radial σ at the raw readings behind it ("" when it holds)."""
    reference = run.reference_field_ut
    figures[f"{prefix}calibrated_field_ut"] = measured
    widening = 0.0
    if fit is not None and raw is not None and (sigma := fit.radial_sigma_ut(raw)) is not None:
        widening = PROOF_Z * float(np.median(sigma))
        figures[f"{prefix}calibrated_field_sigma_ut"] = float(np.median(sigma))
    pct = run.station.verify.field_tolerance_pct
    tolerance_ut = pct / 100.0 * reference + widening
    if abs(measured - reference) <= tolerance_ut:
        return ""
    allowed = f"±{tolerance_ut / reference * 100.0:.1f} %"
    if widening:
        allowed += f": ±{pct:g} % widened by {PROOF_Z:g}σ of the fit in the direction read"
    return (f"the firmware's calibrated field reads {measured:.1f} µT against the reference {reference:.1f} µT "
            f"({(measured / reference - 1.0) * 100.0:+.1f} %, tolerance {allowed}): the calibration is not applied "
            "to this sensor as written, or the sensor's offset moved since its tumble (still warming up?)")
