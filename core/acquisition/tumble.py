"""The default acquire phase (entry point ``tumble_acquisition``, whose module :mod:`.hooks` imports this
one on the first unit): read the unit's stream while it is
turned (an operator's tumble, a gimbal, a coil's schedule through its own plugin), show the live
coverage, and stop when the running fit says the calibration is determined (:mod:`.tumble_stop`) or
the count is read.

``trylast``: a plugin implementing ``magline_acquire`` replaces it (the Helmholtz coil does).  It
drives the DUT through the :class:`~magline.core.dut.DutBackend` protocol only.
"""

from __future__ import annotations

import time
from contextlib import ExitStack, closing, nullcontext
from typing import TYPE_CHECKING

import numpy as np

from magline.core.acquisition.guiding import Guiding, tilt_guide
from magline.core.acquisition.tumble_stop import Stall, running_fit
from magline.core.dut import (
    DutError,
    SampleChunk,
)
from magline.core.faults import StationFault, UnitAborted
from magline.core.fit import CoverageTracker, coverage_of
from magline.core.fit.coverage import CHECK_EVERY, bin_index, covered_bins, sphere_centre
from magline.core.fit.samples_csv import RawSamples
from magline.core.motion import TurnsForTilts
from magline.core.mounting import ImuSeries
from magline.core.sequencer.context import Acquisition, AcquisitionAborted

if TYPE_CHECKING:
    from magline.core.sequencer.context import RunContext

# The running fit is handed the tumble at checkpoints of the primary's count, every 2.5 % more
# readings (at least 3): at 10 Hz about every half second, at 200 Hz every tenth.  Counts, not
# seconds, so that the same readings stop at the same point on any machine.
CHECK_EVERY_FRACTION, CHECK_EVERY_MIN = 0.025, 3
AHEAD_S = 0.5  # a stream this far ahead of the wall clock runs in simulated time: the fit is awaited


def acquire(run: RunContext, attempt: int) -> Acquisition:
    """Read distinct readings until the calibration is determined (``acquisition.stop: determined``:
    coverage and the running fit's predicted σ inside the station's limits with a margin, see
    :mod:`magline.core.fit.running`) or ``acquisition.samples`` arrived.  The count is of readings,
    not of stream messages: a stream faster than the sensor repeats readings, which the backend drops.

    With several magnetometers the primary's count is the one kept to; every other sensor keeps all
    its readings of the same tumble, the stop waits for the last of them to be determined, and the
    coverage shown and judged is the worst sensor's."""
    cfg = run.station.acquisition
    dut = run.require_dut()
    if attempt > 1 or not isinstance(getattr(run.rounds, "motion", None), TurnsForTilts):
        # (a turntable's operator is told each tilt instead of a tumble; a retry still says why first)
        run.prompt(run.station.prompts.tumble if attempt == 1 else run.retry_advice or run.station.prompts.retry)
    tracker = CoverageTracker(cfg.coverage_bins)
    others: dict[int, CoverageTracker] = {}
    got = _Readings(run.unit.selected_sensor if run.unit is not None else 0)
    running = running_fit(run) if cfg.stop == "determined" else None
    reason, tumble_s = "stream ended", 0.0
    final = None  # the determination of every reading the tumble ends with
    advice = None  # why the tumble stalled, in the operator's words, when the motion knows
    stalled_because = ""
    try:
        with run.shared_motion() as number, closing(dut.samples(cfg.rate_hz)) as stream, running or nullcontext(), \
                ExitStack() as on_end:
            started = time.monotonic()  # the fixture moves from here (a slot may have waited for the others)
            deadline, checkpoint = started + cfg.timeout_s, cfg.min_samples
            guide = tilt_guide(run, number, cfg.coverage_bins)
            guiding = Guiding(run, guide) if guide is not None else None
            stall = _stall_rule(run, by_hand=guiding is None and run.station.motion.type == "operator")
            if guiding is not None:
                on_end.callback(guiding.ended)  # this slot no longer speaks for the cradle, however it ended
            for chunk in stream:
                taken = got.add(chunk, room=cfg.samples - got.count)
                seen = got.seen  # readings received: the checkpoints' clock (thinning never turns it back)
                coverage = tracker.add(taken)
                for device_id, more in chunk.more.items():
                    coverage = min(coverage, others.setdefault(device_id, CoverageTracker(cfg.coverage_bins))
                                   .add(np.atleast_2d(more.mag_ut)))
                bins = tracker.bins if not others else min([tracker, *others.values()], key=lambda t: len(t.bins)).bins
                run.progress(attempt, got.seen, coverage, cfg.coverage_target, bins, cfg.coverage_bins)
                now = time.monotonic()
                tumble_s = now - started
                if guiding is not None:  # a turntable: the operator tilts the cradle between the table's turns
                    guidance = guiding.step(chunk, len(taken), tracker.bins)
                    if guidance.state == "stalled":
                        reason, advice = "stalled", f"{guidance.why[:1].upper()}{guidance.why[1:]} — tilt the " \
                                                    f"cradle {guidance.tilt.words} when the station asks"
                        break
                if got.count >= cfg.samples:
                    # the coverage the attempt is judged on: that of the readings held — the live figure counts
                    # readings a thinning let go, and a turntable's attempt stopped at the live 60% was
                    # judged at 55% and tumbled again
                    if running is None or (coverage >= running.rule.coverage_target
                                           and got.coverage(cfg.coverage_bins) >= running.rule.coverage_target
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
                    # on a turntable the readings while the operator tilts are not a stall: only the turns count
                    counted = seen if guiding is None else guiding.turning_seen
                    stall.see(chunk.mag_ut, chunk.imu.accel_mss if chunk.imu is not None else None, counted)
                    if stall.stalled(counted, coverage):
                        reason, stalled_because = "stalled", stall.why
                        if stall.about_vertical_only:
                            advice = run.station.prompts.spun_only
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
    result.stopped, result.tumble_s, result.advice = reason, tumble_s, advice
    result.stalled_because = stalled_because
    if reason == "determined" and final is not None:
        result.predicted = final.predicted
    worst = min(result.coverages, key=result.coverages.get) if result.coverages else None
    mags = result.more[worst].mag_ut if worst in result.more else result.samples.mag_ut
    bins = covered_bins(mags, cfg.coverage_bins)  # the end adds its own checkpoint
    run.progress(attempt, got.seen, result.coverage, cfg.coverage_target, bins, cfg.coverage_bins)
    run.acquisition_stopped(result)
    return result


def _stall_rule(run: RunContext, by_hand: bool) -> Stall:
    """The stall rule of this attempt: the turn about the vertical told only where a person turns the unit
    (a fixture's motion is the station's own, and a turntable's unit turns about the vertical by design),
    read against the site's horizontal field where the field source knows its inclination."""
    cfg = run.station.acquisition
    inclination = getattr(run.field_source, "reference_inclination_deg", None)
    return Stall(cfg.min_samples, cfg.coverage_target, about_vertical=by_hand, field_ut=run.reference_field_ut,
                 inclination_deg=inclination() if callable(inclination) else None)


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
        self.received = 0  # every reading that arrived, a full attempt's let go at once included
        self.span_ms: tuple[float, float] | None = None  # first and last stamp of every reading that arrived

    def add(self, chunk: SampleChunk, room: int | None = None) -> np.ndarray:
        arrived = np.atleast_1d(chunk.t_ms)
        stamps = arrived[np.isfinite(arrived)]
        self.received += len(np.atleast_2d(chunk.mag_ut))
        if len(stamps):
            self.span_ms = (float(stamps[0] if self.span_ms is None else self.span_ms[0]), float(stamps[-1]))
        mag = np.atleast_2d(chunk.mag_ut)[:room] if room is not None else np.atleast_2d(chunk.mag_ut)
        self.mags.append(mag)
        self.times.append(np.atleast_1d(chunk.t_ms)[: len(mag)])
        if chunk.temp_c is not None:
            self.temps.append(np.atleast_1d(chunk.temp_c)[: len(mag)])
        self.count += len(mag)
        self.seen += len(mag)
        self.repeats += chunk.repeats
        return mag

    def rate_hz(self) -> float | None:
        """Distinct readings per second over every reading that arrived — a thinned attempt keeps fewer, and
        its held readings' rate was half the sensor's for every thinning (None below two, or without time)."""
        if self.span_ms is None or self.received < 2 or self.span_ms[1] <= self.span_ms[0]:
            return None
        return float((self.received - 1) / ((self.span_ms[1] - self.span_ms[0]) / 1000.0))

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
        self._coverage: tuple[int, float] | None = None  # (readings read, the held readings' coverage)

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

    def coverage(self, bins: int) -> float:
        """The worst magnetometer's coverage of the readings held: the attempt's own figure.  Computed
        again only every ``CHECK_EVERY`` readings read (its checkpoints): asked at every chunk of a tumble
        gone past its count, it cost a sphere fit per checkpoint each time, and a fast stream's chunks
        come by the hundred a second."""
        if self._coverage is None or self.seen - self._coverage[0] >= CHECK_EVERY:
            self._coverage = (self.seen, min([coverage_of(self.samples().mag_ut, bins),
                                              *(coverage_of(s.samples().mag_ut, bins) for s in self.more.values())]))
        return self._coverage[1]

    def acquisition(self, attempt: int, bins: int, target: float) -> Acquisition:
        samples = self.samples()
        more = {d: s.samples() for d, s in self.more.items()}
        coverages = {self.primary_id: coverage_of(samples.mag_ut, bins)}
        coverages |= {d: coverage_of(s.mag_ut, bins) for d, s in more.items()}
        imu = self.imu_series()
        return Acquisition(attempt=attempt, samples=samples, coverage=min(coverages.values()), target=target,
                           repeats=self.repeats, sensor_rate_hz=self.rate_hz(), more=more, imu=imu,
                           coverages=coverages, read=self.seen)


def _rate_hz(t_ms: np.ndarray) -> float | None:
    """Distinct readings per second over the attempt (None below two readings or without time)."""
    if len(t_ms) < 2 or not np.all(np.isfinite(t_ms)) or t_ms[-1] <= t_ms[0]:
        return None
    return float((len(t_ms) - 1) / ((t_ms[-1] - t_ms[0]) / 1000.0))


# Copies of one reading for this long while the stream's other messages kept coming: the compass is not slow, it
# stopped (a sensor whose bus hung republishes its last sample).  Far beyond any compass's period (10 Hz: 0.1 s).
STUCK_S = 2.0


def _too_slow(got: _Readings, wanted: int, timeout_s: float, elapsed_s: float) -> str:
    """The station's configuration asks more of the sensor than it delivers within the timeout — or the
    compass stopped giving new readings, which no timeout cures."""
    if got.count == 0:
        return f"no readings within {timeout_s:g} s"
    imu = got.imu_series()
    stamps = got.samples().t_ms
    if imu is not None and len(imu.t_ms) and stamps is not None and len(stamps) and got.repeats:
        stopped_s = (float(np.max(imu.t_ms)) - float(np.max(stamps))) / 1000.0
        if stopped_s >= STUCK_S:
            return (f"only {got.count} of {wanted} readings within {timeout_s:g} s: the compass sent no new reading "
                    f"for its last {stopped_s:.0f} s, only copies of one ({got.repeats} dropped) while the unit's "
                    "other readings kept coming — a stuck sensor, not a slow one")
    # The sensor's rate from its own time stamps: the wall clock also counts the stream's start and
    # however busy this machine is; a unit's clock counts only the sensor.
    rate = _rate_hz(got.samples().t_ms) or got.count / elapsed_s
    copies = f"; the stream carried each about {(got.count + got.repeats) / got.count:.0f} times" \
        if got.repeats else ""
    return (f"only {got.count} of {wanted} readings within {timeout_s:g} s: the sensor delivers about "
            f"{rate:.0f} readings/s{copies}, so {wanted} readings take about {wanted / rate:.0f} s — raise "
            "acquisition.timeout_s or lower acquisition.samples")
