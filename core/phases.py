"""The core's default phase implementations (registered like any plugin, entry point ``core_phases``).

Each is ``trylast`` so that a plugin implementing the same ``firstresult`` hook replaces it.
They drive the DUT through the :class:`~magline.core.dut.DutBackend` protocol only, which is what
makes them autopilot-independent.
"""

from __future__ import annotations

import math
import time
from contextlib import closing, nullcontext
from dataclasses import replace

import numpy as np

from magline.core.acquisition.tumble_stop import Stall, running_fit
from magline.core.dut import DutError, HasBootTimeout, LinkError, ParamValue, ReportsSensorsPresent, SampleChunk
from magline.core.faults import StationFault, UnitAborted
from magline.core.fit import CoverageTracker, FitOptions, FitResult, coverage_of, fit_calibration
from magline.core.fit.coverage import bin_index, covered_bins, sphere_centre
from magline.core.fit.samples_csv import RawSamples
from magline.core.measurements import Array, Json, Measurement, Numeric
from magline.core.mounting import ImuSeries, orientation_matrix
from magline.core.plugins import hookimpl
from magline.core.record import PersistReport, VerifyReport
from magline.core.sequencer.context import Acquisition, AcquisitionAborted, RunContext
from magline.core.verify.calibrated_output import calibrated_output_problems

# The running fit is handed the tumble at checkpoints of the primary's count, every 2.5 % more
# readings (at least 3): at 10 Hz about every half second, at 200 Hz every tenth.  Counts, not
# seconds, so that the same readings stop at the same point on any machine.
CHECK_EVERY_FRACTION, CHECK_EVERY_MIN = 0.025, 3
AHEAD_S = 0.5  # a stream this far ahead of the wall clock runs in simulated time: the fit is awaited


@hookimpl(trylast=True)
def magline_acquire(run: RunContext, attempt: int) -> Acquisition:
    """Read distinct readings until the calibration is determined (``acquisition.stop: determined``:
    coverage and the running fit's predicted σ inside the station's limits with a margin, see
    :mod:`magline.core.fit.running`) or ``acquisition.samples`` arrived.  The count is of readings,
    not of stream messages: a stream faster than the sensor repeats readings, which the backend drops.

    With several magnetometers the primary's count is the one kept to; every other sensor keeps all
    its readings of the same tumble, the stop waits for the last of them to be determined, and the
    coverage shown and judged is the worst sensor's."""
    cfg = run.station.acquisition
    dut = run.require_dut()
    run.prompt(run.station.prompts.tumble if attempt == 1 else run.retry_advice or run.station.prompts.retry)
    tracker = CoverageTracker(cfg.coverage_bins)
    others: dict[int, CoverageTracker] = {}
    got = _Readings(run.unit.selected_sensor if run.unit is not None else 0)
    running = running_fit(run) if cfg.stop == "determined" else None
    reason, tumble_s = "stream ended", 0.0
    stall = Stall(cfg.min_samples, cfg.coverage_target)
    final = None  # the determination of every reading the tumble ends with
    try:
        with run.shared_motion(), closing(dut.samples(cfg.rate_hz)) as stream, running or nullcontext():
            started = time.monotonic()  # the fixture moves from here (a slot may have waited for the others)
            deadline, checkpoint = started + cfg.timeout_s, cfg.min_samples
            for chunk in stream:
                taken = got.add(chunk, room=cfg.samples - got.count)
                seen = got.seen  # readings received: the checkpoints' clock (thinning never turns it back)
                coverage = tracker.add(taken)
                for device_id, more in chunk.more.items():
                    coverage = min(coverage, others.setdefault(device_id, CoverageTracker(cfg.coverage_bins))
                                   .add(np.atleast_2d(more.mag_ut)))
                bins = tracker.bins if not others else min([tracker, *others.values()], key=lambda t: len(t.bins)).bins
                run.progress(attempt, got.count, coverage, cfg.coverage_target, bins, cfg.coverage_bins)
                now = time.monotonic()
                tumble_s = now - started
                if got.count >= cfg.samples:
                    if running is None or (coverage >= running.rule.coverage_target
                                           and not running.awaits_drift_test(got.snapshot(run))):
                        reason = "samples"
                        break
                    # a determined tumble still short of its coverage goes on: a fast sensor fills
                    # the count before a slow hand has turned the unit; every other reading is let go
                    # (the only ones of a direction kept), so ``samples`` stays the most it holds.
                    # So does one whose drift test cannot yet judge (a sweep that has not turned
                    # back): ended there, a warm-up would be bent into the soft iron unseen
                    got.thin(cfg.coverage_bins)
                if running is not None:
                    if stall.stalled(seen, coverage):
                        reason = "stalled"
                        break
                    if running.determined is not None:  # a snapshot was: are all the readings?
                        final = running.confirm_now(seen, tumble_s, got.snapshot(run), got.imu_series())
                        if final is not None:
                            reason = "determined"
                            break
                    if coverage >= running.rule.coverage_target and seen >= checkpoint:
                        checkpoint = seen + max(CHECK_EVERY_MIN, int(seen * CHECK_EVERY_FRACTION))
                        snapshot = got.snapshot(run)
                        if len(snapshot) == max(1, len(run.magnetometers)):  # every sensor has readings
                            ahead = _stream_s(snapshot[""]) > tumble_s + AHEAD_S
                            running.offer(seen, tumble_s, snapshot, wait=ahead, imu=got.imu_series())
                            if ahead and running.determined is not None and running.determined.readings == seen:
                                final = running.determined
                                reason = "determined"
                                break
                if now > deadline:
                    if running is not None and got.count >= cfg.min_samples:
                        reason = "timeout"  # readings enough to judge: the coverage and σ limits say the rest
                        break
                    raise StationFault(_too_slow(got, cfg.samples, cfg.timeout_s, now - started))
                run.check_abort()
    except (Exception, UnitAborted) as exc:
        raise AcquisitionAborted(got.acquisition(attempt, cfg.coverage_bins, cfg.coverage_target), exc) from exc
    if got.count == 0:
        raise DutError("the DUT sent no samples")
    result = got.acquisition(attempt, cfg.coverage_bins, cfg.coverage_target)
    result.stopped, result.tumble_s = reason, tumble_s
    if reason == "determined" and final is not None:
        result.predicted = final.predicted
    worst = min(result.coverages, key=result.coverages.get) if result.coverages else None
    mags = result.more[worst].mag_ut if worst in result.more else result.samples.mag_ut
    bins = covered_bins(mags, cfg.coverage_bins)  # the end adds its own checkpoint
    run.progress(attempt, got.count, result.coverage, cfg.coverage_target, bins, cfg.coverage_bins)
    run.acquisition_stopped(result)
    return result


def _stream_s(samples: RawSamples) -> float:
    """Seconds the readings span on their own clock (0 without time stamps)."""
    t = samples.t_ms
    return float((t[-1] - t[0]) / 1000.0) if t is not None and len(t) > 1 and np.all(np.isfinite(t[[0, -1]])) else 0.0


class _Stream:
    """One magnetometer's readings of an attempt: values, times, temperatures, repeats dropped."""

    def __init__(self) -> None:
        self.mags: list[np.ndarray] = []
        self.times: list[np.ndarray] = []
        self.temps: list[np.ndarray] = []
        self.count = 0  # readings held
        self.seen = 0  # readings received (held, or let go by ``thin``)
        self.repeats = 0

    def add(self, chunk: SampleChunk, room: int | None = None) -> np.ndarray:
        mag = np.atleast_2d(chunk.mag_ut)[:room] if room is not None else np.atleast_2d(chunk.mag_ut)
        self.mags.append(mag)
        self.times.append(np.atleast_1d(chunk.t_ms)[: len(mag)])
        if chunk.temp_c is not None:
            self.temps.append(np.atleast_1d(chunk.temp_c)[: len(mag)])
        self.count += len(mag)
        self.seen += len(mag)
        self.repeats += chunk.repeats
        return mag

    def thin(self, n_bins: int) -> None:
        """Let every other reading go, in time order, except in a direction that holds two or fewer:
        the tumble's coverage is what thinning must never cost."""
        held = self.samples()
        if len(held.mag_ut) < 4:
            return
        keep = np.arange(len(held.mag_ut)) % 2 == 0
        where = bin_index(held.mag_ut - sphere_centre(held.mag_ut), n_bins)
        sparse = np.bincount(where, minlength=n_bins) <= 2
        keep |= sparse[where]
        self.mags, self.times = [held.mag_ut[keep]], [held.t_ms[keep]]
        self.temps = [held.temp_c[keep]] if held.temp_c is not None else []
        self.count = int(keep.sum())

    def samples(self) -> RawSamples:
        mag = np.vstack(self.mags) if self.mags else np.empty((0, 3))
        t_ms = np.concatenate(self.times) if self.times else np.empty(0)
        temps = self.temps if self.temps and len(self.temps) == len(self.mags) else None
        return RawSamples(mag_ut=mag, t_ms=t_ms, temp_c=np.concatenate(temps) if temps else None)


class _Readings(_Stream):
    """What an attempt received so far: the primary's readings (an attempt is exactly the samples
    asked for), every other magnetometer's of the same time, and the accelerometer's."""

    def __init__(self, primary_id: int = 0) -> None:
        super().__init__()
        self.primary_id = primary_id
        self.more: dict[int, _Stream] = {}
        self.imu: list[ImuSeries] = []

    def add(self, chunk: SampleChunk, room: int | None = None) -> np.ndarray:
        for device_id, more in chunk.more.items():
            self.more.setdefault(device_id, _Stream()).add(more)
        if chunk.imu is not None and len(chunk.imu):
            self.imu.append(chunk.imu)
        return super().add(chunk, room)

    def thin(self, n_bins: int) -> None:
        """Every magnetometer's readings thinned alike (the accelerometer's are kept: the mounting
        pairs by time, and they are few)."""
        super().thin(n_bins)
        for more in self.more.values():
            more.thin(n_bins)

    def imu_series(self) -> ImuSeries | None:
        """The accelerometer's (and gyro's) readings so far, as one series (None without any)."""
        if not self.imu:
            return None
        gyros = [i.gyro_rads for i in self.imu]
        return ImuSeries(t_ms=np.concatenate([i.t_ms for i in self.imu]),
                         accel_mss=np.vstack([i.accel_mss for i in self.imu]),
                         gyro_rads=np.vstack(gyros) if all(g is not None for g in gyros) else None)

    def snapshot(self, run: RunContext) -> dict[str, RawSamples]:
        """Every calibrated sensor's readings so far, by measurement prefix (what the running fit fits)."""
        out = {}
        for position, sensor in enumerate(run.magnetometers or [None]):
            if position == 0:
                out[""] = self.samples()
            elif sensor is not None and sensor.device_id in self.more:
                out[run.sensor_prefix(sensor.device_id)] = self.more[sensor.device_id].samples()
        return out

    def acquisition(self, attempt: int, bins: int, target: float) -> Acquisition:
        samples = self.samples()
        more = {d: s.samples() for d, s in self.more.items()}
        coverages = {self.primary_id: coverage_of(samples.mag_ut, bins)}
        coverages |= {d: coverage_of(s.mag_ut, bins) for d, s in more.items()}
        imu = self.imu_series()
        return Acquisition(attempt=attempt, samples=samples, coverage=min(coverages.values()), target=target,
                           repeats=self.repeats, sensor_rate_hz=_rate_hz(samples.t_ms), more=more, imu=imu,
                           coverages=coverages)


def _rate_hz(t_ms: np.ndarray) -> float | None:
    """Distinct readings per second over the attempt (None below two readings or without time)."""
    if len(t_ms) < 2 or not np.all(np.isfinite(t_ms)) or t_ms[-1] <= t_ms[0]:
        return None
    return float((len(t_ms) - 1) / ((t_ms[-1] - t_ms[0]) / 1000.0))


def _too_slow(got: _Readings, wanted: int, timeout_s: float, elapsed_s: float) -> str:
    """The station's configuration asks more of the sensor than it delivers within the timeout."""
    if got.count == 0:
        return f"no readings within {timeout_s:g} s"
    # The sensor's rate from its own time stamps: the wall clock also counts the stream's start and
    # however busy this machine is; a unit's clock counts only the sensor.
    rate = _rate_hz(got.samples().t_ms) or got.count / elapsed_s
    copies = f"; the stream carried each about {(got.count + got.repeats) / got.count:.0f} times" \
        if got.repeats else ""
    return (f"only {got.count} of {wanted} readings within {timeout_s:g} s: the sensor delivers about "
            f"{rate:.0f} readings/s{copies}, so {wanted} readings take about {wanted / rate:.0f} s — raise "
            "acquisition.timeout_s or lower acquisition.samples")


@hookimpl(trylast=True)
def magline_fit(run: RunContext, samples: RawSamples, options: FitOptions) -> FitResult:
    return fit_calibration(samples.mag_ut, options, t_ms=samples.t_ms, temp_c=samples.temp_c)


@hookimpl
def magline_validate(run: RunContext, fit: FitResult) -> list[Measurement]:
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


def _same(written: ParamValue, echoed: ParamValue) -> bool:
    if isinstance(written, int) and not isinstance(written, bool):
        return (isinstance(echoed, int) and echoed == written) or (
            isinstance(echoed, float) and echoed.is_integer() and int(echoed) == written)
    # autopilots store float32: compare at float32 precision
    return math.isclose(float(written), float(echoed), rel_tol=1e-6, abs_tol=1e-7)


def calibration_to_write(run: RunContext, fit: FitResult) -> dict[str, ParamValue]:
    """Every fitted magnetometer's parameters (the primary's fit is ``fit``), the orientations the
    mounting check asked to fix, and the custom rotations it measured where the product writes them.
    A sensor whose firmware calibrates in its *rotated* frame (ArduPilot)
    gets its fit turned into the new frame with its new orientation: ``h' = P·h``, ``S' = P·S·Pᵀ``."""
    dut = run.require_dut()
    if not run.unit or not run.unit.magnetometers:
        return dict(dut.calibration_params(fit))
    fixes = run.orientation_fixes
    params: dict[str, ParamValue] = {}
    for sensor in run.magnetometers:
        this = fit if sensor is run.magnetometers[0] else run.fits[sensor.device_id]
        if sensor.device_id in fixes and sensor.readings_rotated:
            turn = orientation_matrix(fixes[sensor.device_id]) @ orientation_matrix(sensor.orientation).T
            this = replace(this, hard_iron_ut=turn @ this.hard_iron_ut, soft_iron=turn @ this.soft_iron @ turn.T)
        params |= dut.calibration_params(this, sensor=sensor.device_id)
        if sensor.device_id in fixes:
            params |= dut.orientation_params(sensor.device_id, fixes[sensor.device_id])
        params |= run.rotation_writes.get(sensor.device_id, {})  # misalignment: write
    return params


@hookimpl(trylast=True)
def magline_persist(run: RunContext, fit: FitResult) -> PersistReport:
    dut = run.require_dut()
    params = calibration_to_write(run, fit)
    before = dut.read_params(list(params))
    run.log(f"writing {len(params)} parameters")
    try:
        echoed = dut.write_params(params)
        wrong = [f"{k}: wrote {v!r}, echoed {echoed.get(k)!r}" for k, v in params.items()
                 if k not in echoed or not _same(v, echoed[k])]
        if wrong:
            raise DutError("parameter write not confirmed: " + "; ".join(wrong))
    except DutError as exc:  # the station's faults (a lost link) stay ERROR: rolled back is not judged
        kind = LinkError if isinstance(exc, StationFault) else DutError
        raise kind(f"{exc}; {_roll_back(run, before)}") from exc
    dut.commit()
    return PersistReport(before=before, written=params, echoed=echoed)


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
                if now is None or not _same(value, now):
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


@hookimpl(trylast=True)
def magline_verify_persistence(run: RunContext, persisted: PersistReport) -> VerifyReport:
    dut = run.require_dut()
    power = run.require_power()
    boot_timeout_s = dut.boot_timeout_s if isinstance(dut, HasBootTimeout) else None
    with run.waiting("power cycle: waiting for the unit to boot", boot_timeout_s):
        figures = dict(power.cycle(dut))
    method = str(figures.pop("method", power.method))
    missing: list[str] = []
    if len(run.magnetometers) > 1 and isinstance(dut, ReportsSensorsPresent):
        now = set(dut.sensors_present())
        missing = [run.sensor_label(m.device_id) for m in run.magnetometers if m.device_id not in now]
        present = not missing
    else:
        present = dut.selected_sensor_present()
    read_back = dut.read_params(list(persisted.written))
    mismatches = [f"{k}: wrote {v!r}, read back {read_back.get(k)!r}" for k, v in persisted.written.items()
                  if k not in read_back or not _same(v, read_back[k])]
    if present:
        mismatches += [f"autopilot reports: {text}" for text in dut.persistence_problems()]
        mismatches += calibrated_output_problems(run, dut, figures)
    return VerifyReport(read_back=read_back, mismatches=mismatches, sensor_present=present,
                        method=method, figures={k: float(v) for k, v in figures.items()}, missing=missing)
