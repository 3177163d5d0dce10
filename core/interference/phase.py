"""The interference sweep as the sequencer runs it (issue 46): measured after the fit with the unit
still, written with the calibration where the product says ``compensate``, and proven after the power
cycle by a second sweep with the compensation the firmware now holds.

Why after the fit: the field change is judged as a share of the calibrated field, in the frame the
firmware will correct in; and for ArduPilot the compensation vector lives after the soft-iron matrix,
so it is computed with the matrix being written.
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from magline.core.dut import CompensatesCurrent, DutError, ParamValue
from magline.core.faults import StationFault
from magline.core.interference.hold import HoldGoal
from magline.core.interference.model import analyse
from magline.core.interference.source import open_current_source
from magline.core.interference.sweep import run_sweep
from magline.core.measurements import Numeric, Verdict

if TYPE_CHECKING:
    from magline.core.dut import Magnetometer
    from magline.core.fit import FitResult
    from magline.core.sequencer.context import RunContext

SWEEP_PROMPT = "Set the unit down in the sweep fixture and keep it still: the current sweep runs"

# The proof sweep's least readings a step.  Why fewer than the measurement's: it judges what the firmware's
# compensation leaves against a limit of 5 % of the field (2.4 µT at 40 A in 48 µT), far above its noise,
# and its readings still rise with the noise to the station's target σ; at 10 Hz compasses a compensated
# unit's two sweeps took 10.3 s with 8.
PROOF_LEAST_READINGS = 4
# A sensor rate measured at this share of the sweep's stream rate or more: the compasses keep pace with it
KEPT_PACE = 0.85


def _source(run: RunContext):
    if run.current_source is None:
        run.current_source = open_current_source(run.station, run.station_dir, run.plugins)
    return run.current_source


def measure(run: RunContext) -> None:
    """The ``interference`` phase: sweep, then each compass's figures for the validate phase."""
    dut = run.require_dut()
    if not isinstance(dut, CompensatesCurrent):
        raise StationFault(f"the {run.product.backend} backend cannot report the unit's current: its current "
                           "interference cannot be measured (interference: off for this product)")
    sweep, fits = _sweep(run, dut, compensation=False)
    field = run.reference_field_ut or run.require_fit().field_ut
    run.interference = analyse(sweep, fits, float(run.product.current_max_a or 0.0), field)
    for sensor in run.magnetometers:
        c = run.interference.compasses[sensor.device_id]
        run.log(f"{run.sensor_label(sensor.device_id)}: {c.ut_per_a:.3f} ± {c.per_amp_sigma_ut:.3f} µT/A, "
                f"{c.pct_at_max:.1f} % of the field at {run.product.current_max_a:g} A")
    run.record.unit_info["interference"] = run.interference.to_dict()


def _note(run: RunContext, note: str) -> None:
    run.log(note)
    run.record.unit_info.setdefault("interference_notes", []).append(note)


def goal_note(run: RunContext, device_id: int) -> str | None:
    """For a compass being compensated whose written slope is known less well than the station's goal
    (the budget held the sweep's ends too short for its noise and its small interference): how well it
    is known, so a process engineer can weigh a longer budget or a quieter compass."""
    settings = run.station.interference
    found = run.interference
    c = found.compasses[device_id]
    if c.known_pct <= settings.compensation_goal_pct:
        return None
    note = (f"{run.sensor_label(device_id)}: its compensation is known to ±{c.known_pct:.0f} % of its interference, "
            f"not the goal's {settings.compensation_goal_pct:g} %: the {settings.compensation_budget_s:g} s budget "
            f"held the top and 0 A for {found.held_readings} readings more of the {found.hold_asked} the goal asked")
    # the tumble's stream says whether the compasses are faster than the sweep's: every reading new at the
    # sweep's rate means they may publish faster, and a faster sweep stream holds more readings in the budget
    rates = [a.sensor_rate_hz for a in run.record.attempts if a.sensor_rate_hz]
    if found.stream_hz and rates and rates[-1] >= KEPT_PACE * found.stream_hz:
        note += (f" (the compasses kept pace with a {rates[-1]:.0f} Hz stream: a faster interference.rate_hz than "
                 f"{found.stream_hz:g} holds more readings in the budget, where the link carries it)")
    return note


def params_for(run: RunContext, sensor: Magnetometer, fit: FitResult, turn: NDArray | None) -> dict[str, ParamValue]:
    """The compensation parameters of one compass (``turn``: the orientation fix its fit was turned by),
    for the persist phase; empty unless the product compensates.  A firmware without them: the unit is
    measured and judged, and the note says it cannot be compensated on that firmware."""
    if run.product.interference != "compensate" or run.interference is None:
        return {}
    dut = run.require_dut()
    if not isinstance(dut, CompensatesCurrent):
        return {}
    found = run.interference.compasses[sensor.device_id]
    if not found.worth_writing:
        _note(run, f"{run.sensor_label(sensor.device_id)}: current interference not compensated: its field per amp "
                   f"({np.linalg.norm(found.per_amp_written_ut):.4f} ± {found.written_sigma_ut:.4f} µT/A per axis) is "
                   "within the sweep's noise — writing it would add about as much as it removes")
        return {}
    per_amp = found.per_amp_written_ut
    if turn is not None:
        per_amp = turn @ per_amp
    try:
        params = dict(dut.interference_params(sensor.device_id, per_amp, fit))
    except DutError as exc:
        _note(run, f"{run.sensor_label(sensor.device_id)}: current interference not compensated: {exc}")
        return {}
    run.interference.compensated.add(sensor.device_id)
    note = goal_note(run, sensor.device_id)
    if note:
        _note(run, note)
    return params


def switch_on(run: RunContext, written: dict[str, ParamValue]) -> dict[str, ParamValue]:
    """The firmware's compensation switch, when a compass's compensation is being written."""
    dut = run.dut
    if not written or not isinstance(dut, CompensatesCurrent):
        return {}
    return dict(dut.compensation_params())


def prove(run: RunContext) -> None:
    """After the power cycle: sweep again with the compensation the firmware holds; what its corrected
    field still changes at the top current is judged (``interference_left_pct_at_max``)."""
    if run.product.interference != "compensate" or run.interference is None:
        return
    dut = run.require_dut()
    if not isinstance(dut, CompensatesCurrent) or not run.interference.compensated:
        return  # nothing compensated (a firmware without the parameters): measured and judged only
    sweep, fits = _sweep(run, dut, compensation=True)
    identity = {d: _identity(f) for d, f in fits.items()}  # the stream's own frame: the firmware says the rest
    again = analyse(sweep, identity, run.interference.current_max_a, run.interference.field_ut)
    proof = {}
    failed = []
    for sensor in run.magnetometers:
        if sensor.device_id not in run.interference.compensated:
            continue
        stream_slope = again.compasses[sensor.device_id].per_amp_written_ut
        left = np.asarray(dut.left_per_amp_ut(sensor.device_id, stream_slope), float)
        pct = float(np.linalg.norm(left) * run.interference.current_max_a / run.interference.field_ut * 100.0)
        measured = Numeric.of(run.sensor_prefix(sensor.device_id) + "interference_left_pct_at_max", pct, run.limits)
        run.record.measurements.append(measured)
        proof[str(sensor.device_id)] = {"left_per_amp_ut": left.tolist(), "left_pct_at_max": pct,
                                        "sigma_ut_per_a": again.compasses[sensor.device_id].per_amp_sigma_ut}
        if measured.verdict is Verdict.FAIL:
            failed.append(f"{run.sensor_label(sensor.device_id)}: the compensated field still changes {pct:.1f} % of "
                          f"the field at {run.interference.current_max_a:g} A (limit {measured.high:g} %)")
    found = run.record.unit_info.setdefault("interference", {})
    found["proof"], found["proof_seconds"] = proof, again.seconds
    if failed:  # the unit does not hold what was written: its FAIL, as a calibration that did not survive
        raise DutError("current compensation not proven after the power cycle: " + "; ".join(failed))


def _sweep(run: RunContext, dut: CompensatesCurrent, compensation: bool) -> tuple:
    """One sweep with the unit set down: the measurement (compensation off, the station's levels) or the
    proof (what the firmware holds on, 0 / top / 0: only the slope left matters); with every compass's fit."""
    source = _source(run)
    run.prompt(SWEEP_PROMPT)
    source.start(run)
    dut.measure_current_interference(compensation=compensation)
    settings = run.station.interference
    goal = None
    if compensation:  # only the slope left matters, to the same ±σ: the noise decides the readings from 4 up
        settings = settings.model_copy(update={"steps": 1, "readings": min(settings.readings, PROOF_LEAST_READINGS)})
    elif run.product.interference == "compensate" and _can_compensate(run, dut):
        goal = HoldGoal(share=settings.compensation_goal_pct / 100.0, budget_s=settings.compensation_budget_s)
    sweep = run_sweep(run, source, settings, [m.device_id for m in run.magnetometers], goal)
    return sweep, {**run.fits, run.magnetometers[0].device_id: run.require_fit()}


def _can_compensate(run: RunContext, dut: CompensatesCurrent) -> bool:
    """Whether the firmware can hold any compass's compensation: where it cannot, the sweep is not held
    at its ends for slopes nobody will write (the persist phase's note says why)."""
    missing = [dut.compensation_missing(m.device_id) for m in run.magnetometers]
    if all(missing):
        run.log(f"the sweep is not held for the compensation goal: {missing[0]}")
        return False
    return True


def _identity(fit: FitResult) -> FitResult:
    """The proof reads the stream's own frame: what the firmware does with it is the backend's to say."""
    return replace(fit, hard_iron_ut=np.zeros(3), soft_iron=np.eye(3))
