"""The core's default fit, validate and persist phases (registered like any plugin, entry point
``core_phases``; the acquire phase is :mod:`magline.core.acquisition.tumble`, the verify phase
:mod:`magline.core.verify.phase`).

Each is ``trylast`` so that a plugin implementing the same ``firstresult`` hook replaces it.
They drive the DUT through the :class:`~magline.core.dut.DutBackend` protocol only, which is what
makes them autopilot-independent.
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

from magline.core.dut import (
    DutError,
    LinkError,
    ParamValue,
    StoresFactoryCalibration,
    param_equal,
)
from magline.core.faults import StationFault
from magline.core.measurements import Array, Json, Measurement, Numeric
from magline.core.plugins import hookimpl
from magline.core.record import PersistReport

if TYPE_CHECKING:
    from magline.core.fit import FitOptions, FitResult
    from magline.core.fit.samples_csv import RawSamples
    from magline.core.sequencer.context import RunContext


@hookimpl(trylast=True)
def magline_fit(run: RunContext, samples: RawSamples, options: FitOptions) -> FitResult:
    from magline.core.fit import fit_calibration  # on use: every command loads this plugin

    return fit_calibration(samples.mag_ut, options, t_ms=samples.t_ms, temp_c=samples.temp_c)


@hookimpl
def magline_validate(run: RunContext, fit: FitResult) -> list[Measurement]:
    import numpy as np  # on use: every command loads this plugin

    lim = run.limits
    h = fit.hard_iron_ut
    s = fit.soft_iron
    offdiag = max(abs(s[0, 1]), abs(s[0, 2]), abs(s[1, 2])) / float(np.mean(np.diag(s)))
    out: list[Measurement] = [
        Numeric.of("hard_iron_x_ut", h[0], lim),
        Numeric.of("hard_iron_y_ut", h[1], lim),
        Numeric.of("hard_iron_z_ut", h[2], lim),
        Numeric.of("hard_iron_norm_ut", float(np.linalg.norm(h)), lim),
        Numeric.of("hard_iron_sigma_ut", float(np.linalg.norm(fit.hard_iron_sigma_ut)), lim),
        Numeric.of("axis_ratio", fit.axis_ratio, lim),
        Numeric.of("soft_iron_offdiag_max", offdiag, lim),
        Numeric.of("residual_rms_ut", fit.residual_rms_ut, lim),
        Numeric.of("residual_max_ut", fit.residual_max_ut, lim),
        Numeric.of("field_ut", fit.field_ut, lim),
        Numeric.of("coverage", fit.coverage, lim),
        Numeric.of("direction_sigma_deg", fit.direction_sigma_deg, lim),
        # readings judged bad (clipped, spikes); the warm-up the drift test leaves out is its own figure:
        # a statistical alarm (10⁻³ on good units) must not become a verdict by the readings it sets aside
        Numeric.of("rejected_fraction", sum(n for k, n in fit.rejected.items() if k != "warm_up")
                   / fit.samples_total, lim),
        Numeric.of("warm_up_fraction", fit.rejected.get("warm_up", 0) / fit.samples_total, lim),
        Numeric.of("attempts", len(run.attempts), lim),
        Array.of("residual_ut", fit.residuals_ut, lim),
        Json(name="calibration", data={"hard_iron_ut": h.tolist(), "soft_iron": s.tolist(),
                                       "field_ut": fit.field_ut, "model": fit.model}),
    ]
    if fit.raw_to_reference_ratio is not None:
        out.append(Numeric.of("field_error_pct", (fit.raw_to_reference_ratio - 1.0) * 100.0, lim))
    if fit.model_misfit is not None:
        out.append(Numeric.of("model_misfit_deg", fit.model_misfit["direction_error_deg"], lim))
    if fit.drift is not None and fit.drift.get("detectable_ut") is not None:
        out.append(Numeric.of("drift_detectable_ut", fit.drift["detectable_ut"], lim))
    return out


def calibration_to_write(run: RunContext, fit: FitResult) -> dict[str, ParamValue]:
    """Every fitted magnetometer's parameters (the primary's fit is ``fit``), the orientations the
    mounting check asked to fix, and the custom rotations it measured where the product writes them.
    A sensor whose firmware calibrates in its *rotated* frame (ArduPilot)
    gets its fit turned into the new frame with its new orientation: ``h' = P·h``, ``S' = P·S·Pᵀ``."""
    from magline.core.interference import phase as interference
    from magline.core.mounting import orientation_matrix

    dut = run.require_dut()
    if not run.unit or not run.unit.magnetometers:
        return dict(dut.calibration_params(fit))
    fixes = run.orientation_fixes
    params: dict[str, ParamValue] = {}
    compensation: dict[str, ParamValue] = {}
    for sensor in run.magnetometers:
        this = fit if sensor is run.magnetometers[0] else run.fits[sensor.device_id]
        turn = None
        if sensor.device_id in fixes and sensor.readings_rotated:
            turn = orientation_matrix(fixes[sensor.device_id]) @ orientation_matrix(sensor.orientation).T
            this = replace(this, hard_iron_ut=turn @ this.hard_iron_ut, soft_iron=turn @ this.soft_iron @ turn.T)
        params |= dut.calibration_params(this, sensor=sensor.device_id)
        if sensor.device_id in fixes:
            params |= dut.orientation_params(sensor.device_id, fixes[sensor.device_id])
        params |= run.rotation_writes.get(sensor.device_id, {})  # misalignment: write
        compensation |= interference.params_for(run, sensor, this, turn)  # interference: compensate
    return params | compensation | interference.switch_on(run, compensation)


@hookimpl(trylast=True)
def magline_persist(run: RunContext, fit: FitResult) -> PersistReport:
    dut = run.require_dut()
    params = calibration_to_write(run, fit)
    before = dut.read_params(list(params))
    run.log(f"writing {len(params)} parameters")
    try:
        echoed = dut.write_params(params)
        wrong = [f"{k}: wrote {v!r}, echoed {echoed.get(k)!r}" for k, v in params.items()
                 if k not in echoed or not param_equal(v, echoed[k])]
        if wrong:
            raise DutError("parameter write not confirmed: " + "; ".join(wrong))
    except DutError as exc:  # the station's faults (a lost link) stay ERROR: rolled back is not judged
        kind = LinkError if isinstance(exc, StationFault) else DutError
        raise kind(f"{exc}; {_roll_back(run, before)}") from exc
    dut.commit()
    factory = _store_in_factory(run) if run.product.persist == "factory-storage" else None
    return PersistReport(before=before, written=params, echoed=echoed, store=run.product.persist, factory=factory)


def _store_in_factory(run: RunContext) -> dict:
    """``persist: factory-storage``: the firmware copies the parameters just written and saved into its
    factory store.  A refusal or a failure (the unit moved, no partition) is kept, not raised: the
    parameters are proven through the power cycle all the same, and the unit then ends as an ERROR
    that says the factory store was not written (the sequencer's verify)."""
    dut = run.require_dut()
    if not isinstance(dut, StoresFactoryCalibration):
        raise StationFault(f"the {run.product.backend} backend has no factory calibration store "
                           "(products.<part>.persist: factory-storage)")
    mode_after = run.product.factory_cal_mode_after
    run.log("copying the calibration into the firmware's factory calibration store")
    try:
        said = dut.store_factory_calibration(mode_after)
    except DutError as exc:
        if isinstance(exc, StationFault):
            raise
        run.log(f"factory calibration store not written: {exc}")
        return {"written": False, "said": str(exc), "mode_after": mode_after}
    run.log(f"factory calibration store written: {said}")
    return {"written": True, "said": said, "mode_after": mode_after}


def _roll_back(run: RunContext, before: dict[str, ParamValue]) -> str:
    """A write failed part-way: put the previous values back so no half calibration stays behind.

    Each parameter on its own: the one that was refused usually still holds its old value, which
    a read confirms; only a parameter that is neither restored nor unchanged is a real problem.  Once
    the link is lost the rest is not tried (each would wait out its retries on a silent link)."""
    dut = run.require_dut()
    stuck = []
    lost: str | None = None
    for name, value in before.items():
        if lost is None:
            try:
                dut.write_params({name: value})
                continue
            except LinkError as exc:
                lost = str(exc)
            except Exception:
                try:
                    now = dut.read_params([name]).get(name)
                except Exception:
                    now = None
                if now is None or not param_equal(value, now):
                    stuck.append(f"{name} = {now!r} (was {value!r})")
                continue
        stuck.append(f"{name} = unknown (was {value!r})")  # the link is gone: not tried
    if lost is not None:
        run.log(f"rollback stopped: {lost}")
    if stuck:
        run.log("rollback failed for " + "; ".join(stuck))
        return "ROLLBACK FAILED for " + ", ".join(s.split(" =")[0] for s in stuck) + \
            " — the unit may hold a partial calibration; quarantine it"
    run.log(f"rolled back {len(before)} parameters to their previous values")
    return "previous values restored"


