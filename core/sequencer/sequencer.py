"""Run one unit through the phases, in order, with outcomes, durations and logs.

Rules the sequencer enforces whatever the plugins do:
* an exception in a plugin ends the unit with the cause, classified once for every backend and
  instrument (:mod:`magline.core.faults`): FAIL when the unit was judged bad, ERROR when the station
  could not judge it, ABORTED when the operator stopped it; it never propagates to the station loop;
* raw samples are stored the moment an attempt ends (or is interrupted), before fitting;
* persist runs only when validation passed; verify only when persist succeeded;
* the DUT is restored and closed, and the record stored, on every path — shielded from a second
  Ctrl-C; what could not be restored, and a calibration written but not proven, is said plainly.
"""

from __future__ import annotations

import threading
import time
import traceback
from collections.abc import Callable
from contextlib import ExitStack
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

from magline.core import __version__
from magline.core.dut import CalibratesSeveral, DutError, LinkError, Magnetometer, NotRestored, ReportsUptime
from magline.core.faults import StationFault, UnitAborted
from magline.core.field import FieldSourceError
from magline.core.fit import FitRefused, FitResult
from magline.core.interference import phase as interference
from magline.core.lazy import warm_imports
from magline.core.measurements import Json, Verdict, limit_for, prefixed, verdicts
from magline.core.plugins import Plugins
from magline.core.record import AttemptRecord, Outcome, PersistReport, PhaseResult, RunRecord, now_iso
from magline.core.results.sinks import open_results
from magline.core.sequencer.abort import AbortSwitch
from magline.core.sequencer.context import AcquisitionAborted, RunContext
from magline.core.sequencer.hold import (
    claimed_in_store,
    fixture_locks,
    holder_of,
    holding,
    store_identity,
    unit_locks,
)
from magline.core.sequencer.rounds import MotionRounds
from magline.core.sequencer.settling import offset_moved
from magline.core.sequencer.unit_log import unit_log_capture
from magline.core.sequencer.warm_up import wait_until_warm
from magline.core.serials import clean_serial, known_part
from magline.core.text import fmt, percent

if TYPE_CHECKING:
    from magline.core.sequencer.context import Acquisition
    from magline.core.station.schema import Slot, Station

PHASES = ("identify", "connect", "acquire", "fit", "interference", "validate", "persist", "verify", "record")
OPTIONAL_PHASES = ("interference",)  # run only for the products that ask for it (``interference`` not off)
SHIELDED_PHASES = ("persist",)  # a half-written calibration is worse than a few seconds' wait
RETEST = "re-test the unit"
# What a unit's tumble computes with (the running fit, the mounting's estimate): imported when the station
# starts (:func:`~magline.core.lazy.warm_imports`), since a command imports only what it uses
TUMBLE_MODULES = ("magline.core.acquisition.tumble", "magline.core.fit.geometric", "magline.core.mounting.checks",
                  "scipy.optimize", "scipy.spatial.transform", "scipy.interpolate")


class PhaseFailed(Exception):
    """A phase ended with a FAIL verdict (the unit is bad, not the station)."""


class Sequencer:
    """Runs units for one station file; holds the station-wide field source and results sink."""

    def __init__(self, station: Station, plugins: Plugins, station_dir: Path | str = ".",
                 sleep: Callable[[float], None] = time.sleep) -> None:
        warm_imports(*TUMBLE_MODULES)  # made while the unit connects, not in the middle of its tumble
        self.station = station
        self.plugins = plugins
        self.station_dir = Path(station_dir)
        self.sleep = sleep
        self.abort = AbortSwitch()
        self.sink = open_results(station, self.station_dir, plugins)
        kind = station.field_source.type
        self.field_source = plugins.field_sources[kind](
            station, plugins.options("field source", kind, station.field_source.options, "field_source.options",
                                    self.station_dir))
        motion_factory = plugins.motions.get(station.motion.type)
        if motion_factory is None:
            raise StationFault(f"no motion named {station.motion.type!r} is loaded "
                               f"(loaded: {', '.join(sorted(plugins.motions))})")
        self.motion = motion_factory(station, self.station_dir, plugins.options(
            "motion", station.motion.type, station.motion.options, "motion.options", self.station_dir))
        self.stopped: str | None = None  # why the batch was stopped (the cell's field is not trusted)
        self.shared_lock = threading.RLock()  # slots running side by side share the field source
        # Slots create their backends and open their links one at a time: MAVSDK's native instance
        # creation crashed the process (segfault, illegal instruction) when it ran while another slot
        # thread imported pymavlink or created its own instance — about one four-board load in five.
        # A link opens in about a second; the shared tumble, which is what slots save time on, is unaffected.
        self.connect_lock = threading.Lock()

    def rounds(self, slots: list[str]) -> MotionRounds:
        """The shared motion's rounds for these slots (listeners hear each round start and stop)."""
        kind = self.station.motion.type
        return MotionRounds(
            self.motion, slots,
            started=lambda r, s: self.plugins.hook.magline_motion_started(round=r, slots=s, motion=kind),
            stopped=lambda r, s: self.plugins.hook.magline_motion_stopped(round=r, slots=s, motion=kind))

    def close(self) -> None:
        for obj in (self.field_source, self.sink, self.motion):
            closer = getattr(obj, "close", None)
            if closer is not None:
                closer()

    # ------------------------------------------------------------------ one unit
    def run_unit(self, serial: str, part: str | None = None, operator: str = "", slot: Slot | None = None,
                 rounds: MotionRounds | None = None, abort: AbortSwitch | None = None,
                 slot_group: str | None = None, held: bool = False) -> RunRecord:
        """One unit through every phase.  On a station with slots the slot runner calls this once per
        slot, each on its own thread, with the slot, the shared motion's rounds and the slot's own
        abort switch, having taken the load's locks and claims itself (``held``); alone, the unit has
        the motion to itself and takes its own.  A part the station does not build, a serial that
        breaks its rule (:class:`Refused`) or anything shared held by another run (``StationBusy``)
        is refused before any record exists."""
        station = self.station
        part = slot.part if slot is not None else part or station.default_part or next(iter(station.products))
        known_part(part, list(station.products), station.station.id)
        product = station.slot_product(slot) if slot is not None else station.products[part]
        serial = clean_serial(serial, product)
        record = RunRecord(serial=serial, part=part, station_id=station.station.id,
                           line=station.station.line, operator=operator,
                           software_version=__version__, limit_hash=station.limit_hash(part),
                           station_hash=station.content_hash(),
                           slot=slot.id if slot is not None else None, slot_group=slot_group)
        slot_id = slot.id if slot is not None else ""
        run = RunContext(station=station, station_dir=self.station_dir, part=part,
                         product=product, serial=serial, operator=operator,
                         plugins=self.plugins, record=record, limits=station.effective_limits(part),
                         abort=abort or self.abort, slot=slot.id if slot is not None else None,
                         rounds=rounds or self.rounds([slot_id]), results=self.sink)
        steps: list[tuple[str, Callable[[RunContext], Any]]] = [
            ("identify", self._identify), ("connect", self._connect), ("acquire", self._acquire),
            ("fit", self._fit), ("validate", self._validate), ("persist", self._persist),
            ("verify", self._verify),
        ]
        if product.interference != "off":  # the current sweep, the unit still, once it is calibrated
            steps.insert(4, ("interference", interference.measure))
        if self.stopped is not None:
            steps = [("identify", self._identify), ("connect", self._refuse_stopped_batch)]
        with ExitStack() as stack:
            if not held:
                holder = self.holder(serial, record.slot)
                shared = unit_locks(station, self.station_dir, product, record.slot)
                if slot is None:  # alone on the fixture: its instruments are this unit's for the run
                    shared = fixture_locks(station) + shared
                stack.enter_context(holding(shared, holder))  # StationBusy before any record
                stack.enter_context(claimed_in_store(self.sink, holder))
            stack.enter_context(unit_log_capture(record, this_thread_only=slot is not None))
            return self._run_steps(run, steps)

    def holder(self, serial: str, slot: str | None) -> dict:
        """Who holds this station's locks and claims for a unit: as a refusal names them."""
        return holder_of(serial, self.station.station.id, slot, str(self.station_dir.resolve()),
                         store_identity(self.station, self.station_dir))

    def _run_steps(self, run: RunContext, steps: list[tuple[str, Callable[[RunContext], Any]]]) -> RunRecord:
        record = run.record
        verdict: Outcome | None = None
        try:
            for name, step in steps:
                if verdict is not None:
                    record.phases.append(PhaseResult(name=name, outcome=Outcome.SKIPPED))
                    continue
                outcome = self._run_phase(run, name, step)
                if outcome is not Outcome.PASS:
                    verdict = outcome
                    record.cause = record.phases[-1].message
        except UnitAborted as exc:  # between phases: charged to the last phase that ran
            last = record.phases[-1].name if record.phases else "identify"
            verdict, record.cause, record.aborted_phase = Outcome.ABORTED, f"{exc.reason} after {last}", last
        finally:
            run.rounds.leave(run.slot or "")  # the shared motion never waits for a unit that has ended
            with run.abort.shielded():
                self._cleanup(run)
        with run.abort.shielded():
            record.verdict = self._conclude(record, verdict or Outcome.PASS)
            if self._run_phase(run, "record", self._record) is not Outcome.PASS:
                record.store = ""  # never reported as stored
                note = f"the record could not be stored ({record.phases[-1].message}); {RETEST}"
                record.cause = f"{record.cause} — {note}" if record.cause else note
                if record.verdict in (Outcome.PASS, Outcome.FAIL):
                    record.verdict = Outcome.ERROR  # a judgement nobody can trace does not count
            # reports, screens, plant feeds … listen; one that raises is a warning on the record, never the verdict
            self.plugins.notify("magline_unit_finished", record.listener_faults, run=run, record=record)
        return record

    def _run_phase(self, run: RunContext, name: str, step: Callable[[RunContext], Any]) -> Outcome:
        result = PhaseResult(name=name)
        run._phase = result
        run.record.phases.append(result)
        self.plugins.notify("magline_phase_started", run.record.listener_faults, run=run, phase=name)
        start = time.monotonic()
        run.phase_started_at = start
        try:
            if name in SHIELDED_PHASES:
                with run.abort.shielded():
                    step(run)
            else:
                run.abort.check()
                step(run)
            result.outcome = Outcome.PASS
        except UnitAborted as exc:
            result.outcome = Outcome.ABORTED
            result.message = f"{exc.reason} during {name}"
            run.record.aborted_phase = name
        except FieldSourceError as exc:  # the cell, not the unit: stop the batch
            result.outcome = Outcome.ERROR
            result.message = f"batch stopped: {_text(exc)}"
            self.stopped = str(exc)
        except StationFault as exc:  # no or lost link, instrument, supply: the unit was not judged
            result.outcome = Outcome.ERROR
            result.message = _text(exc)
        except (PhaseFailed, DutError, FitRefused) as exc:
            result.outcome = Outcome.FAIL
            result.message = _text(exc)
        except Exception as exc:  # a plugin bug must not crash the station
            result.outcome = Outcome.ERROR
            result.message = f"internal error in the {name} phase: {_text(exc)} (details in the record's log)"
            result.log.append(traceback.format_exc(limit=6))
        result.duration_s = time.monotonic() - start
        if result.message:
            result.log.append(result.message)
        run._phase = None
        self.plugins.notify("magline_phase_finished", run.record.listener_faults, run=run, phase=name, result=result)
        return result.outcome

    def _conclude(self, record: RunRecord, verdict: Outcome) -> Outcome:
        """The unit's verdict once the DUT is released: what was left changed or written but not
        proven is said in the cause, and a unit that cannot ship as it is never passes."""
        written_not_proven = record.params_written and not record.params_read_back and verdict in (
            Outcome.ERROR, Outcome.ABORTED)
        if written_not_proven:
            record.unverified_params = list(record.params_written)
            record.cause += (f" — the unit now holds a new, unverified calibration ({len(record.unverified_params)} "
                             f"parameters: {', '.join(record.unverified_params)}); {RETEST}")
        if record.left_changed:
            changed = ", ".join(f"{k} left at {v}" for k, v in record.left_changed.items())
            note = f"the unit could not be restored: {changed}; {RETEST}"
            record.cause = f"{record.cause} — {note}" if record.cause else note
            if verdict is Outcome.PASS:
                return Outcome.ERROR
        return verdict

    # ------------------------------------------------------------------ phases
    def _identify(self, run: RunContext) -> None:
        run.log(f"unit {run.serial}, part {run.part}, limit set {run.record.limit_hash}")
        self._count_earlier_runs(run)
        _kept(self.plugins.hook.magline_unit_started(run=run), f"no results store began the run of {run.serial}")

    def _count_earlier_runs(self, run: RunContext) -> None:
        """A re-test is allowed, but said: the record keeps how many runs and passes came before."""
        earlier = run.results.history(run.serial) if run.results is not None else []  # the sink contract's own
        passes = [r for r in earlier if r.get("verdict") == Outcome.PASS]
        run.record.earlier_runs, run.record.earlier_passes = len(earlier), len(passes)
        if passes:
            last = passes[-1]
            run.prompt(f"Re-test: {run.serial} already passed (run {last.get('id')}, {str(last.get('started'))[:16]}); "
                       f"this is test {len(earlier) + 1} of this unit")
        elif earlier:
            run.log(f"re-test: {len(earlier)} earlier run(s) of {run.serial}, none passed")

    def _refuse_stopped_batch(self, run: RunContext) -> None:
        raise FieldSourceError(self.stopped)

    def _connect(self, run: RunContext) -> None:
        factory = self.plugins.dut_backends.get(run.product.backend)
        if factory is None:
            raise StationFault(f"no DUT backend named {run.product.backend!r} is loaded")
        power_factory = self.plugins.power_controls.get(run.product.power.method)
        if power_factory is None:
            raise StationFault(f"no power control named {run.product.power.method!r} is loaded")
        run.field_source = self.field_source
        with self.shared_lock:
            run.reference_field_ut = run.record.reference_field_ut = self.field_source.reference_field_ut()
            # what the line's dashboard shows of the cell's field (a source that can say it: the live check's last)
            describe = getattr(self.field_source, "describe", None)
            run.record.field_check = describe() if callable(describe) else None
        run.log(f"reference field {run.reference_field_ut:.2f} µT")
        power = run.product.power
        run.power = power_factory(power, self.station_dir, self.plugins.options(
            "power control", power.method, power.options, f"products.{run.part}.power.options", self.station_dir))
        run.power.power_up()
        with self.connect_lock:  # slots open their links one at a time (see __init__)
            run.dut = factory(run.product, self.plugins.options("dut backend", run.product.backend,
                                                                run.product.options, f"products.{run.part}.options",
                                                                self.station_dir))
            run.unit = run.dut.connect()
        run.record.unit_info = {
            "autopilot": run.unit.autopilot, "firmware": run.unit.firmware,
            "sensors": run.unit.sensors, "selected_sensor": run.unit.selected_sensor,
            "soft_iron_model": run.unit.soft_iron_model, **run.unit.extra,
        }
        run.magnetometers = _chosen_magnetometers(run)
        run.record.unit_info["magnetometers"] = [
            {"prefix": run.sensor_prefix(m.device_id).rstrip("."), "device_id": m.device_id, "label": m.label,
             "external": m.external, "orientation": m.orientation} for m in run.magnetometers]
        if run.unit.magnetometers and isinstance(run.dut, CalibratesSeveral):
            run.dut.use_magnetometers([m.device_id for m in run.magnetometers])
        names = ", ".join(run.sensor_label(m.device_id) for m in run.magnetometers)
        run.log(f"{run.unit.autopilot} {run.unit.firmware}, magnetometer{'s' if len(run.magnetometers) > 1 else ''} "
                f"{names}")
        why = run.unit.extra.get("soft_iron_model_why")
        run.log(f"soft iron model {run.fit_options().model}" + (f": {why}" if why else ""))
        run.dut.prepare()

    def _acquire(self, run: RunContext) -> None:
        """Acquire until the samples determine the calibration, or the retries run out.

        Coverage decides whether an attempt is worth fitting; the fit itself decides whether the
        samples determine the calibration (its refusal is the stronger check), and its advice
        becomes the operator's prompt for the next attempt.
        """
        try:
            self._let_warm_up(run)
            self._acquire_attempts(run)
        finally:
            run.rounds.leave(run.slot or "")  # accepted or given up: the next rounds go without this unit

    def _let_warm_up(self, run: RunContext) -> None:
        """``acquisition.warm_up_s``: the tumble waits until the unit has run that long (see
        :mod:`~magline.core.sequencer.warm_up`).  The wait is real time whatever ``self.sleep`` is: it
        waits for the board's temperature, which no test double advances."""
        need = self.station.acquisition.warm_up_s
        if need <= 0:
            return
        reader = run.dut.uptime_s if isinstance(run.dut, ReportsUptime) else None

        def uptime() -> float | None:
            if reader is None:
                return None
            try:
                return reader()
            except DutError as exc:
                if isinstance(exc, LinkError):  # a lost link is the station's fault, as anywhere
                    raise
                run.log(f"the unit did not say its uptime ({_text(exc)}): warm-up counted from now")
                return None

        with ExitStack() as waiting:
            def told(left_s: float) -> None:
                run.prompt(f"Leave the unit on and still — it warms up for {left_s:.0f} s before its tumble")
                waiting.enter_context(run.waiting("warming up before the tumble", limit_s=left_s))

            warm = wait_until_warm(need, uptime, told, run.check_abort)
        run.record.unit_info["warm_up"] = {"uptime_s": warm.uptime_s, "waited_s": round(warm.waited_s, 2)}
        run.log(warm.words(need))

    def _acquire_attempts(self, run: RunContext) -> None:
        acq = self.station.acquisition
        refusal: FitRefused | None = None
        warm: dict[int, FitResult] | None = None  # the fits of the last attempt refused for a warm-up
        for attempt in range(1, acq.retries + 2):
            if attempt > 1:
                self.sleep(acq.retry_delay_s)
            try:
                result = self.plugins.hook.magline_acquire(run=run, attempt=attempt)
            except AcquisitionAborted as exc:  # keep what arrived before the failure, then classify the cause
                stored = self._store_attempt(run, exc.partial, accepted=False)
                cause = exc.cause
                stored.refused = f"interrupted: {_text(cause) if not isinstance(cause, UnitAborted) else cause.reason}"
                cause.add_note(f"after {len(exc.partial.samples)} readings; raw data kept")
                raise cause from None
            run.attempts.append(result)
            stored = self._store_attempt(run, result, accepted=result.sufficient)
            run.log(f"attempt {attempt}: {_readings_line(result)}, coverage {percent(result.coverage)} "
                    f"(target {percent(result.target)})")
            if not result.sufficient:
                run.retry_advice, refusal = result.advice, None
                stored.refused = f"coverage {percent(result.coverage)} below the target {percent(result.target)}"
                if len(result.coverages) > 1:  # the retry is for the worst sensor: say which
                    worst = min(result.coverages, key=result.coverages.get)
                    stored.refused += f" ({run.sensor_label(worst)})"
                    run.retry_advice = (f"Coverage too low for {run.sensor_label(worst)} "
                                        f"({percent(result.coverage)}) — {run.station.prompts.retry}")
                continue
            started = time.monotonic()
            try:
                fits = self._fit_every_sensor(run, result)
            except FitRefused as exc:
                if exc.reason == "warm_up" and acq.retry_on_warm_up and attempt <= acq.retries:
                    # the drift left the calibration undetermined: a warm-up, measured again like one caught
                    refusal, warm = None, None
                    stored.accepted, stored.refused = False, f"warm-up: {exc.message}"
                    run.retry_advice = f"The magnetometer was still warming up — {again_words(run)}"
                    run.log(f"attempt {attempt}: {exc.message}: measured again (acquisition.retry_on_warm_up)")
                    continue
                refusal = exc
                stored.accepted, stored.refused = False, f"{exc.reason}: {exc.message}"
                run.retry_advice = exc.advice[:1].upper() + exc.advice[1:]
                run.log(f"attempt {attempt}: calibration refused: {exc.message}")
                continue
            warming = _warming_up(run, fits) if acq.retry_on_warm_up and attempt <= acq.retries else ""
            moved = "" if warming or warm is None else offset_moved(  # settled since the warm-up?
                warm, fits, run.sensor_label, partial(_accepted_offset_sigma, run))
            if moved and attempt > acq.retries:
                run.log(f"attempt {attempt}: {moved}: the last attempt, calibrated as it is")
            elif moved:
                warming = moved
            if warming:  # a settling sensor: measured again, not calibrated on its way (see Acquisition)
                refusal, warm = None, fits
                stored.accepted, stored.refused = False, f"warm-up: {warming}"
                run.retry_advice = f"The magnetometer was still warming up — {again_words(run)}"
                run.log(f"attempt {attempt}: {warming}: measured again (acquisition.retry_on_warm_up)")
                continue
            run.fits = fits
            run.fit = fits[run.magnetometers[0].device_id]
            run.fit_s = time.monotonic() - started
            return
        if refusal is not None:
            raise FitRefused(refusal.reason, f"{refusal.message} (after {len(run.attempts)} attempts)",
                             refusal.advice)
        raise PhaseFailed(f"coverage {percent(run.attempts[-1].coverage)} below the target "
                          f"{percent(acq.coverage_target)} after {len(run.attempts)} attempts")

    def _fit_every_sensor(self, run: RunContext, result: Acquisition) -> dict[int, FitResult]:
        """One fit per magnetometer with the same engine; the first refusal refuses the attempt, its
        message and advice naming the sensor (the operator's retry is for the worst sensor)."""
        fits: dict[int, FitResult] = {}
        for position, sensor in enumerate(run.magnetometers):
            samples = result.samples if position == 0 else result.more.get(sensor.device_id)
            label = run.sensor_label(sensor.device_id)
            if samples is None or len(samples) == 0:
                raise DutError(f"{label} sent no readings during the tumble")
            try:
                fits[sensor.device_id] = self.plugins.hook.magline_fit(run=run, samples=samples,
                                                                       options=run.fit_options(sensor))
            except FitRefused as exc:
                if len(run.magnetometers) == 1:
                    raise
                raise FitRefused(exc.reason, f"{label}: {exc.message}", f"{label}: {exc.advice}") from exc
        return fits

    def _store_attempt(self, run: RunContext, result: Acquisition, accepted: bool) -> AttemptRecord:
        stored = AttemptRecord(attempt=result.attempt, samples=len(result.samples), coverage=result.coverage,
                               target=result.target, raw=result.samples, accepted=accepted,
                               repeats=result.repeats, sensor_rate_hz=result.sensor_rate_hz,
                               more=dict(result.more), imu=result.imu, stopped=result.stopped,
                               tumble_s=result.tumble_s, predicted=dict(result.predicted))
        run.record.attempts.append(stored)
        _kept(self.plugins.hook.magline_attempt_ended(run=run, attempt=stored),  # raw data safe before any fitting
              f"no results store kept the readings of attempt {stored.attempt}")
        return stored

    def _fit(self, run: RunContext) -> None:
        """Record the fits that the accepted attempt produced (the acquire phase ran them)."""
        fit = run.require_fit()
        run.record.calibration = fit.to_dict()
        for sensor in run.magnetometers[1:]:
            other = run.fits[sensor.device_id]
            prefix = run.sensor_prefix(sensor.device_id).rstrip(".")
            run.record.calibration.setdefault("magnetometers", {})[prefix] = {
                "device_id": sensor.device_id, **other.to_dict()}
            run.log(f"{run.sensor_label(sensor.device_id)}: offset {other.hard_iron_ut.round(2).tolist()} µT, "
                    f"residual rms {other.residual_rms_ut:.3f} µT")
        run.log(f"offset {fit.hard_iron_ut.round(2).tolist()} µT, field {fit.field_ut:.2f} µT, "
                f"residual rms {fit.residual_rms_ut:.3f} µT (fitted in {run.fit_s * 1e3:.0f} ms, "
                "during acquisition)")
        if fit.model_misfit:
            mis = fit.model_misfit
            run.log(f"soft iron not representable by the {mis['model']} model this autopilot holds: residual "
                    f"{mis['residual_ut']:.2f} µT against {mis['full_model_residual_ut']:.2f} µT for the full "
                    f"matrix, heading cost up to {mis['direction_error_deg']:.2f}°")
        if fit.bias_correction and fit.bias_correction["iterations"] > 1:
            run.log(f"second-order bias removed in {fit.bias_correction['iterations']} steps "
                    f"({fit.bias_correction['largest_sigmas']:.1f}σ): partial coverage")

    def _validate(self, run: RunContext) -> None:
        fit = run.require_fit()
        for contribution in self.plugins.hook.magline_validate(run=run, fit=fit):
            run.record.measurements.extend(contribution)
        for sensor in run.magnetometers[1:]:
            prefix = run.sensor_prefix(sensor.device_id)
            for contribution in self.plugins.hook.magline_validate(run=run, fit=run.fits[sensor.device_id]):
                run.record.measurements.extend(prefixed(contribution, prefix, run.limits))
        judged_bad = any(m.verdict is Verdict.FAIL for m in verdicts(run.record.measurements))
        try:
            for contribution in self.plugins.hook.magline_validate_unit(run=run, fits=dict(run.fits)):
                run.record.measurements.extend(contribution)
        except StationFault as exc:
            if not judged_bad:
                raise
            # The unit FAILs on its own figures already (a fit its firmware cannot hold leaves residuals the
            # mounting cannot be proven through): what the station could not prove beside them does not
            # make it unjudged — ERROR is for a unit the station could not judge, and yield counts on it.
            run.record.unit_info["not_judged"] = str(exc)
            run.log(f"beside the failed figures, not judged: {exc}")
        failed = [m for m in verdicts(run.record.measurements) if m.verdict is Verdict.FAIL]
        review = [m for m in verdicts(run.record.measurements) if m.verdict is Verdict.REVIEW]
        for m in review:
            run.log(f"review: {m.name} = {fmt(m.value, m.unit)} is within the marginal band")
        if failed:
            message = "; ".join(m.note or f"{m.name} = {fmt(m.value, m.unit)} outside [{fmt(m.low)}, {fmt(m.high)}]"
                                for m in failed)
            if any(m.name == "field_error_pct" for m in failed):
                message += (" — the field magnitude the unit measures does not match the reference: "
                            "calibration has failed regardless of fit residual")
            raise PhaseFailed(message)
        self.plugins.hook.magline_unit_judged(run=run, measurements=verdicts(run.record.measurements))

    def _persist(self, run: RunContext) -> None:
        report: PersistReport = self.plugins.hook.magline_persist(run=run, fit=run.require_fit())
        run.persisted = report
        run.record.params_before = dict(report.before)
        run.record.params_written = dict(report.written)
        run.record.params_echoed = dict(report.echoed)
        run.record.measurements.append(Json(name="params_written", data=dict(report.written)))

    def _verify(self, run: RunContext) -> None:
        report = self.plugins.hook.magline_verify_persistence(run=run, persisted=run.persisted)
        run.record.params_read_back = dict(report.read_back)
        run.record.persistence = {"method": report.method, "figures": report.figures,
                                  "sensor_present": report.sensor_present, "mismatches": report.mismatches,
                                  "store": report.store or run.persisted.store}
        if not report.sensor_present:
            missing = ", ".join(report.missing) or f"magnetometer {run.unit.selected_sensor}"
            raise PhaseFailed(f"{missing} missing after power cycle")
        if report.mismatches:
            raise PhaseFailed("calibration did not survive the power cycle: " + "; ".join(report.mismatches))
        factory = run.persisted.factory
        if factory is not None and not factory.get("written"):  # proven as parameters, not where it was asked
            raise StationFault(f"the factory calibration store was not written ({factory.get('said')}); the "
                               "calibration is proven as ordinary parameters only — test the unit again")
        interference.prove(run)  # the current compensation written, proven by a second sweep

    def _record(self, run: RunContext) -> None:
        run.record.finished = now_iso()
        phase = run.record.phases[-1]  # this phase: stored with its real outcome, timed up to the write
        phase.outcome, phase.duration_s = Outcome.PASS, time.monotonic() - run.phase_started_at
        run.record.store = "; ".join(_kept(self.plugins.hook.magline_record_unit(run=run, record=run.record),
                                           "no results store kept the record"))

    def _cleanup(self, run: RunContext) -> None:
        """Always: put the DUT back as it was, release it, then leave the fixture in its final state."""
        steps = [(run.current_source, "stop"), (run.current_source, "close"), (run.dut, "restore"), (run.dut, "close"),
                 (run.power, "finish"), (run.power, "close"), (run.field_source, "finish_unit")]
        for target, action in steps:
            if target is None:
                continue
            try:
                if target is run.field_source:
                    with self.shared_lock:
                        getattr(target, action)()
                else:
                    getattr(target, action)()
            except NotRestored as exc:
                run.record.left_changed.update(exc.left_changed)
                run.record.phases[-1].log.append(str(exc))
            except Exception as exc:
                run.record.phases[-1].log.append(f"{action} failed: {_text(exc)}")


def _chosen_magnetometers(run: RunContext) -> list[Magnetometer]:
    """The magnetometers this run calibrates, the primary first: every one the unit has (``all``, the
    default), the station file's list (device ids, or positions in the firmware's order), or only the
    one the backend selected (``magnetometer: <id>`` alone, or a backend that knows one sensor).
    A listed sensor the unit lacks fails the unit, naming it."""
    unit = run.require_unit()
    have = list(unit.magnetometers)
    if not have:
        return [Magnetometer(device_id=unit.selected_sensor, label="magnetometer")]
    wanted = run.product.magnetometers
    if wanted is None:
        wanted = "all" if run.product.magnetometer == "primary" else [unit.selected_sensor]
    if wanted == "all":
        chosen = have
    else:
        chosen, missing = [], []
        for entry in wanted:
            by_id = next((m for m in have if m.device_id == entry), None)
            found = by_id or (have[entry - 1] if 1 <= entry <= min(len(have), 9) else None)
            if found is None:
                missing.append(f"magnetometer {entry}")
            elif found not in chosen:
                chosen.append(found)
        if missing:
            listed = ", ".join(f"{m.label} ({m.device_id})" for m in have)
            raise DutError(f"{', '.join(missing)} listed for {run.part} {'is' if len(missing) == 1 else 'are'} not on "
                           f"this unit; it has {listed}")
    primary = next((m for m in chosen if m.device_id == unit.selected_sensor), chosen[0])
    return [primary, *(m for m in chosen if m is not primary)]


def _accepted_offset_sigma(run: RunContext, device_id: int) -> float:
    """The station's upper limit on a sensor's offset σ (``hard_iron_sigma_ut``), 0 when it sets none."""
    limit = limit_for(run.sensor_prefix(device_id) + "hard_iron_sigma_ut", run.limits)
    return float(limit.high) if limit is not None and limit.high is not None else 0.0


def _warming_up(run: RunContext, fits: dict[int, FitResult]) -> str:
    """What the fits caught of a warm-up, each sensor named when there are several ("" when none)."""
    caught = [(run.sensor_label(device_id), words) for device_id, fit in fits.items()
              if (words := fit.warm_up_caught)]
    return "; ".join(f"{label}: {words}" if len(fits) > 1 else words for label, words in caught)


def again_words(run: RunContext) -> str:
    """What the operator does for another attempt: tumble, or nothing (a coil or gimbal measures)."""
    return "tumble again" if run.unit_moves else "measuring again"


def _kept(answers: list[str], nobody: str) -> list[str]:
    """The stores that answered a record hook; none is the station's fault (an ERROR), never a unit
    judged with nothing kept — the store listener disabled, or a plugin manager without it."""
    if not answers:
        raise StationFault(f"{nobody} (is the results_store plugin disabled?)")
    return answers


def _text(exc: BaseException) -> str:
    """An exception as an operator reads it: its message and notes, no class name."""
    notes = "".join(f" ({n})" for n in getattr(exc, "__notes__", ()))
    return (str(exc) or type(exc).__name__) + notes


def _readings_line(result: Acquisition) -> str:
    line = f"{len(result.samples)} readings"
    if result.repeats:
        line += f" (the stream repeated readings {result.repeats} times; dropped)"
    if result.sensor_rate_hz:
        line += f", sensor {result.sensor_rate_hz:.0f} readings/s"
    return line
