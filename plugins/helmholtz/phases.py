"""What the coil plugin's acquire, fit and validate hooks do (:mod:`magline.plugins.helmholtz.plugin`): each
answers only when the station's field source is the coil (or the samples carry the applied field), else
``None``."""

from __future__ import annotations

import time
from contextlib import closing
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from magline.plugin import DutError, Numeric, RawSamples
from magline.plugins.helmholtz.source import (
    HelmholtzField,
    applied_bins,
    applied_share,
    schedule,
)

if TYPE_CHECKING:
    from magline.plugin import Acquisition, FitOptions, FitResult, RunContext, StopRule


def acquire(run: RunContext, attempt: int) -> Acquisition | None:
    """Step the coil through its schedule, reading the unit at each applied vector.

    With ``acquisition.stop: determined`` the unit leaves the schedule once the readings so far
    determine its calibration: the share of the schedule's directions applied at least the station's
    ``coverage_target``, at least ``min_samples`` readings, and the affine fit's predicted σ inside the
    station's limits with the margin (the tumble's rule, :func:`magline.plugin.stop_rule`).
    The schedule's order makes every beginning of it well spread; on a slot station the others go on
    without the unit, and the coil is switched off when the last one has left."""
    from magline.plugin import Acquisition, stop_rule

    source = run.field_source
    if not isinstance(source, HelmholtzField):
        return None
    opts = source.opts
    cfg = run.station.acquisition
    steps = schedule(opts)
    rule = stop_rule(run) if cfg.stop == "determined" else None
    if source.shift_report:  # the shift checks' figures travel with the unit that triggered them
        run.log("coil shift checks: " + ", ".join(f"{k} {v}" for k, v in source.shift_report.items()))
        source.shift_report = {}
    run.prompt("Place the unit at the coil centre and do not touch it")
    mags, times, applied = [], [], []
    dut = run.require_dut()
    slot = run.slot or ""
    reason, predicted, share = "samples", {}, 0.0
    # every unit in the coil (one per slot) steps through the same schedule: each vector applied once
    with run.shared_motion() as round_number, closing(dut.samples(cfg.rate_hz)) as stream:
        members = run.rounds.members if run.rounds is not None else [slot]
        shared = source.shared_schedule(round_number or 0, members, steps)
        started = time.monotonic()
        try:
            for index, vector in enumerate(steps):
                shared.step(slot, index, run.check_abort)
                settled = time.monotonic() + opts.settle_s
                next(stream)  # samples in flight (queued by the link) were taken in the previous field
                while time.monotonic() < settled:
                    next(stream)
                got = 0
                while got < opts.samples_per_step:
                    chunk = next(stream, None)
                    if chunk is None:
                        raise DutError("the DUT stopped sending samples during the coil schedule")
                    take = np.atleast_2d(chunk.mag_ut)[: opts.samples_per_step - got]
                    mags.append(take)
                    times.append(np.atleast_1d(chunk.t_ms)[: len(take)])
                    applied.append(np.tile(vector, (len(take), 1)))
                    got += len(take)
                share = applied_share(np.vstack(applied), steps)
                readings = sum(len(m) for m in mags)
                run.progress(attempt, readings, share, cfg.coverage_target,
                             applied_bins(np.vstack(applied), opts.directions), opts.directions)
                if rule is not None and share >= cfg.coverage_target and readings >= rule.min_samples:
                    figures = _determined(rule, np.vstack(mags), np.vstack(applied), opts.field_ut, share)
                    if figures is not None:
                        reason, predicted = "determined", figures
                        break
        finally:
            shared.leave(slot)  # the last unit out sets the field to zero
    samples = RawSamples(mag_ut=np.vstack(mags), t_ms=np.concatenate(times), applied_ut=np.vstack(applied))
    result = Acquisition(attempt=attempt, samples=samples, coverage=share,
                         target=cfg.coverage_target, stopped=reason, tumble_s=time.monotonic() - started,
                         predicted=predicted)
    run.acquisition_stopped(result)
    return result


def _determined(rule: StopRule, mag_ut: np.ndarray, applied_ut: np.ndarray, field_ut: float,
                share: float) -> dict[str, dict[str, float]] | None:
    """The rule's predicted figures once the readings so far determine the calibration, else None
    (judged with the schedule's share as the coverage, so a station's ``coverage`` limit holds too)."""
    from magline.plugin import FitRefused, fit_affine

    try:
        fit = fit_affine(mag_ut, applied_ut, field_ut)
    except FitRefused:
        return None
    return rule.judge({"": replace(fit, coverage=share)})


def fit(run: RunContext, samples: RawSamples, options: FitOptions) -> FitResult | None:
    from magline.plugin import fit_affine

    if samples.applied_ut is None:
        return None
    fit = fit_affine(samples.mag_ut, samples.applied_ut, options.field_ut)
    if isinstance(run.field_source, HelmholtzField):  # the coverage a coil's schedule gave, as its progress said
        fit = replace(fit, coverage=applied_share(samples.applied_ut, schedule(run.field_source.opts)))
    run.log(f"misalignment {fit.extra['misalignment_deg']:.3f}° to the coil frame "
            f"(rotation vector {np.round(fit.extra['misalignment_rotvec_deg'], 3).tolist()}°)")
    return fit


def validate(run: RunContext, fit: FitResult) -> list | None:
    if fit.model != "affine":
        return []
    return [Numeric.of("misalignment_deg", fit.extra["misalignment_deg"], run.limits)]
