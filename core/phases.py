"""The core's default phase implementations (registered like any plugin, entry point ``core_phases``).

Each is ``trylast`` so that a plugin implementing the same ``firstresult`` hook replaces it.
They drive the DUT through the :class:`~magline.core.dut.DutBackend` protocol only, which is what
makes them autopilot-independent.
"""

from __future__ import annotations

import math
import time
from contextlib import closing

import numpy as np

from magline.core.dut import DutError, ParamValue, SampleChunk
from magline.core.faults import StationFault, UnitAborted
from magline.core.fit import CoverageTracker, FitOptions, FitResult, coverage_of, fit_calibration
from magline.core.fit.coverage import covered_bins
from magline.core.fit.samples_csv import RawSamples
from magline.core.measurements import Array, Json, Measurement, Numeric
from magline.core.plugins import hookimpl
from magline.core.record import PersistReport, VerifyReport
from magline.core.sequencer.context import Acquisition, AcquisitionAborted, RunContext


@hookimpl(trylast=True)
def magline_acquire(run: RunContext, attempt: int) -> Acquisition:
    """Read distinct readings until ``acquisition.samples`` arrived (the count is of readings, not
    of stream messages: a stream faster than the sensor repeats readings, which the backend drops)."""
    cfg = run.station.acquisition
    dut = run.require_dut()
    run.prompt(run.station.prompts.tumble if attempt == 1 else run.retry_advice or run.station.prompts.retry)
    tracker = CoverageTracker(cfg.coverage_bins)
    got = _Readings()
    try:
        with run.shared_motion(), closing(dut.samples(cfg.rate_hz)) as stream:
            started = time.monotonic()  # the fixture moves from here (a slot may have waited for the others)
            deadline = started + cfg.timeout_s
            for chunk in stream:
                taken = got.add(chunk, room=cfg.samples - got.count)
                coverage = tracker.add(taken)
                run.progress(attempt, got.count, coverage, cfg.coverage_target, tracker.bins, cfg.coverage_bins)
                if got.count >= cfg.samples:
                    break
                if time.monotonic() > deadline:
                    raise StationFault(_too_slow(got, cfg.samples, cfg.timeout_s, time.monotonic() - started))
                run.check_abort()
    except (Exception, UnitAborted) as exc:
        raise AcquisitionAborted(got.acquisition(attempt, cfg.coverage_bins, cfg.coverage_target), exc) from exc
    if got.count == 0:
        raise DutError("the DUT sent no samples")
    result = got.acquisition(attempt, cfg.coverage_bins, cfg.coverage_target)
    bins = covered_bins(result.samples.mag_ut, cfg.coverage_bins)  # the end adds its own checkpoint
    run.progress(attempt, got.count, result.coverage, cfg.coverage_target, bins, cfg.coverage_bins)
    return result


class _Readings:
    """What an attempt received so far: readings, times, temperatures, repeats dropped."""

    def __init__(self) -> None:
        self.mags: list[np.ndarray] = []
        self.times: list[np.ndarray] = []
        self.temps: list[np.ndarray] = []
        self.count = 0
        self.repeats = 0

    def add(self, chunk: SampleChunk, room: int) -> np.ndarray:
        """Keep at most ``room`` readings of the chunk (an attempt is exactly the samples asked for)."""
        mag = np.atleast_2d(chunk.mag_ut)[:room]
        self.mags.append(mag)
        self.times.append(np.atleast_1d(chunk.t_ms)[: len(mag)])
        if chunk.temp_c is not None:
            self.temps.append(np.atleast_1d(chunk.temp_c)[: len(mag)])
        self.count += len(mag)
        self.repeats += chunk.repeats
        return mag

    def acquisition(self, attempt: int, bins: int, target: float) -> Acquisition:
        mag = np.vstack(self.mags) if self.mags else np.empty((0, 3))
        t_ms = np.concatenate(self.times) if self.times else np.empty(0)
        temps = self.temps if self.temps and len(self.temps) == len(self.mags) else None
        samples = RawSamples(mag_ut=mag, t_ms=t_ms, temp_c=np.concatenate(temps) if temps else None)
        return Acquisition(attempt=attempt, samples=samples, coverage=coverage_of(mag, bins), target=target,
                           repeats=self.repeats, sensor_rate_hz=_rate_hz(t_ms))


def _rate_hz(t_ms: np.ndarray) -> float | None:
    """Distinct readings per second over the attempt (None below two readings or without time)."""
    if len(t_ms) < 2 or not np.all(np.isfinite(t_ms)) or t_ms[-1] <= t_ms[0]:
        return None
    return float((len(t_ms) - 1) / ((t_ms[-1] - t_ms[0]) / 1000.0))


def _too_slow(got: _Readings, wanted: int, timeout_s: float, elapsed_s: float) -> str:
    """The station's configuration asks more of the sensor than it delivers within the timeout."""
    if got.count == 0:
        return f"no readings within {timeout_s:g} s"
    rate = got.count / elapsed_s
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
        Numeric.of("rejected_fraction", 1.0 - fit.samples_used / fit.samples_total, lim),
        Numeric.of("attempts", len(run.attempts), lim),
        Array.of("residual_ut", fit.residuals_ut, lim),
        Json(name="calibration", data={"hard_iron_ut": h.tolist(), "soft_iron": s.tolist(),
                                       "field_ut": fit.field_ut, "model": fit.model}),
    ]
    if fit.raw_to_reference_ratio is not None:
        out.append(Numeric.of("field_error_pct", (fit.raw_to_reference_ratio - 1.0) * 100.0, lim))
    if fit.model_misfit is not None:
        out.append(Numeric.of("model_misfit_deg", fit.model_misfit["direction_error_deg"], lim))
    return out


def _same(written: ParamValue, echoed: ParamValue) -> bool:
    if isinstance(written, int) and not isinstance(written, bool):
        return (isinstance(echoed, int) and echoed == written) or (
            isinstance(echoed, float) and echoed.is_integer() and int(echoed) == written)
    # autopilots store float32: compare at float32 precision
    return math.isclose(float(written), float(echoed), rel_tol=1e-6, abs_tol=1e-7)


@hookimpl(trylast=True)
def magline_persist(run: RunContext, fit: FitResult) -> PersistReport:
    dut = run.require_dut()
    params = dut.calibration_params(fit)
    before = dut.read_params(list(params))
    run.log(f"writing {len(params)} parameters")
    try:
        echoed = dut.write_params(params)
        wrong = [f"{k}: wrote {v!r}, echoed {echoed.get(k)!r}" for k, v in params.items()
                 if k not in echoed or not _same(v, echoed[k])]
        if wrong:
            raise DutError("parameter write not confirmed: " + "; ".join(wrong))
    except DutError as exc:
        raise DutError(f"{exc}; {_roll_back(run, before)}") from exc
    dut.commit()
    return PersistReport(before=before, written=params, echoed=echoed)


def _roll_back(run: RunContext, before: dict[str, ParamValue]) -> str:
    """A write failed part-way: put the previous values back so no half calibration stays behind.

    Each parameter on its own: the one that was refused usually still holds its old value, which
    a read confirms; only a parameter that is neither restored nor unchanged is a real problem."""
    dut = run.require_dut()
    stuck = []
    for name, value in before.items():
        try:
            dut.write_params({name: value})
        except Exception:
            try:
                now = dut.read_params([name]).get(name)
            except Exception:
                now = None
            if now is None or not _same(value, now):
                stuck.append(f"{name} = {now!r} (was {value!r})")
    if stuck:
        run.log("rollback failed for " + "; ".join(stuck))
        return "ROLLBACK FAILED for " + ", ".join(s.split(" =")[0] for s in stuck) + \
            " — the unit may hold a partial calibration; quarantine it"
    run.log(f"rolled back {len(before)} parameters to their previous values")
    return "previous values restored"


CALIBRATED_READINGS = 20


def _calibrated_output_problems(run: RunContext, dut: object, figures: dict) -> list[str]:
    """The proof on the firmware's own terms: after the power cycle, the unit's *calibrated* output
    must read the reference field.  A read-back only proves that what was written is stored; a
    calibration written to a slot the firmware does not apply to this sensor, or with a wrong sign
    or unit, is stored just as well — and reads far off here.  Backends that can read their
    calibrated output implement ``calibrated_field_ut(count)`` (None: not attributable here); field
    sources whose reference is the field the unit sits in say ``reference_is_ambient = True``
    (a coil's generated field is gone after its schedule)."""
    read = getattr(dut, "calibrated_field_ut", None)
    reference = run.reference_field_ut
    if read is None or not reference or not getattr(run.field_source, "reference_is_ambient", False):
        return []
    readings = read(CALIBRATED_READINGS)
    if readings is None or len(readings) == 0:
        return []
    measured = float(np.median(np.linalg.norm(np.atleast_2d(readings), axis=1)))
    off_pct = (measured / reference - 1.0) * 100.0
    figures["calibrated_field_ut"] = measured
    tolerance = run.station.verify.field_tolerance_pct
    if abs(off_pct) <= tolerance:
        return []
    return [f"the firmware's calibrated field reads {measured:.1f} µT against the reference {reference:.1f} µT "
            f"({off_pct:+.1f} %, tolerance ±{tolerance:g} %): the calibration is not applied to this sensor as written"]


@hookimpl(trylast=True)
def magline_verify_persistence(run: RunContext, persisted: PersistReport) -> VerifyReport:
    dut = run.require_dut()
    power = run.require_power()
    with run.waiting("power cycle: waiting for the unit to boot", getattr(dut, "boot_timeout_s", None)):
        figures = dict(power.cycle(dut))
    method = str(figures.pop("method", power.method))
    present = dut.selected_sensor_present()
    read_back = dut.read_params(list(persisted.written))
    mismatches = [f"{k}: wrote {v!r}, read back {read_back.get(k)!r}" for k, v in persisted.written.items()
                  if k not in read_back or not _same(v, read_back[k])]
    if present:
        mismatches += [f"autopilot reports: {text}" for text in dut.persistence_problems()]
        mismatches += _calibrated_output_problems(run, dut, figures)
    return VerifyReport(read_back=read_back, mismatches=mismatches, sensor_present=present,
                        method=method, figures={k: float(v) for k, v in figures.items()})
