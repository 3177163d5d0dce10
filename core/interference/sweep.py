"""The current sweep: the unit still, the current stepped from 0 to the product's ``current_max_a``
and back to 0, every compass read at each step with the unit's own current reading.

Why up *and* down: a part magnetised by the current (a screw, a shield) leaves a field once the
current is off again, and a warming board drifts; either shows as a difference between the first
and the last zero step — a finding, not noise (``interference_return_ut``).  Why the unit's own
reading beside the source's: the firmware compensates with what *its* current sensor says, so the
vector written is fitted against that, while the physical figure is fitted against the load's
measurement, and the two disagreeing is a power module's wrong scale.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from magline.core.dut import DutBackend, DutError, SampleChunk
from magline.core.faults import StationFault, StreamTooFast
from magline.core.interference.hold import plan_for_goal, readings_in_budget

if TYPE_CHECKING:
    from magline.core.interference.hold import HoldGoal
    from magline.core.interference.source import CurrentSource
    from magline.core.sequencer.context import RunContext
    from magline.core.station.schema import InterferenceSettings


NO_CURRENT_S = 3.0  # compasses read, and still no current reading from the unit: it has none
# The sweep's stream where the station file sets no ``interference.rate_hz``: as fast as common compasses
# publish (a faster stream only repeats their readings); a serial line that cannot carry it gets what it can
DEFAULT_STREAM_HZ = 100.0
LEAST_STREAM_HZ = 5.0  # below this a line is refused even for the default: a sweep would outlast its timeout


@dataclass
class HeardInStep:
    """Everything the unit sent while a step was read, each reading with its stamp on the unit's clock.
    Why kept whole: which readings came after the step's level settled is decided on the unit's clock as
    known when the step ends, not as it was known when each reading arrived (:func:`_read_step`)."""

    mag: dict[int, list[tuple[NDArray, NDArray]]] = field(default_factory=dict)  # device id → (stamps, µT rows)
    current: list[tuple[float, float]] = field(default_factory=list)  # (stamp, the unit's current reading A)
    accel: list[tuple[NDArray, NDArray]] = field(default_factory=list)  # (stamps, m/s² rows)
    repeats: dict[int, int] = field(default_factory=dict)  # device id → copies of a reading dropped

    def add(self, chunk: SampleChunk, device_ids: list[int]) -> None:
        for device_id, readings in ((device_ids[0], chunk), *chunk.more.items()):
            if device_id in device_ids:
                self.mag.setdefault(device_id, []).append(
                    (np.asarray(readings.t_ms, float).ravel(), np.asarray(readings.mag_ut, float).reshape(-1, 3)))
                self.repeats[device_id] = self.repeats.get(device_id, 0) + readings.repeats
        currents = np.asarray(chunk.current_a, float).ravel()
        stamps = np.asarray(chunk.current_t_ms, float).ravel()
        self.current.extend((float(t), float(a)) for a, t in zip(currents, stamps, strict=False))
        if chunk.imu is not None and len(chunk.imu.accel_mss):
            self.accel.append((np.asarray(chunk.imu.t_ms, float).ravel(),
                               np.asarray(chunk.imu.accel_mss, float).reshape(-1, 3)))


def _stamped_from(parts: list[tuple[NDArray, NDArray]], from_ms: float) -> list[NDArray]:
    return [row for stamps, rows in parts for row in rows[stamps >= from_ms]]


@dataclass
class SweepStep:
    level: float
    source_a: float | None = None  # what the source measured at the end of the step (None: it cannot)
    firmware_a: list[float] = field(default_factory=list)  # the unit's own current readings after the settle
    readings: dict[int, list[NDArray]] = field(default_factory=dict)  # device id → raw readings (µT)
    accel: list[NDArray] = field(default_factory=list)  # accelerometer readings (m/s², body axes)
    heard: HeardInStep = field(default_factory=HeardInStep, repr=False, compare=False)

    def fields(self, device_id: int) -> NDArray:
        return np.array(self.readings.get(device_id, []), float).reshape(-1, 3)

    @property
    def firmware_mean_a(self) -> float | None:
        return float(np.mean(self.firmware_a)) if self.firmware_a else None

    def settled_from(self, from_ms: float) -> None:
        """The step's readings, current readings and accelerometer: what it heard stamped at ``from_ms`` or
        later on the unit's clock."""
        self.readings = {d: _stamped_from(parts, from_ms) for d, parts in self.heard.mag.items()}
        self.firmware_a = [a for t, a in self.heard.current if t >= from_ms]
        self.accel = _stamped_from(self.heard.accel, from_ms)


@dataclass
class Sweep:
    steps: list[SweepStep]
    seconds: float
    device_ids: list[int]
    readings_per_step: int = 0  # what the noise at 0 A asked for (the station's ``readings`` at least)
    held_readings: int = 0  # read more at the top and the last zero in all, for a compensation goal (:mod:`.hold`)
    hold_asked: int = 0  # what the goal asked for there in all (more than held: the budget cut it)
    stream_hz: float = 0.0  # the rate the sweep's stream was asked for


def sweep_levels(steps: int) -> list[float]:
    """0, 1/steps, …, 1 and back down to 0: ``2·steps + 1`` levels."""
    up = [k / steps for k in range(steps + 1)]
    return up + up[-2::-1]


class UnitClock:
    """The unit's stream time now, from the chunks as they arrive.  Why its own stamps: a chunk gathers
    readings until it is full (a second at a 10 Hz compass), so the readings of a step are told from the
    ones before it by their own stamps, not by when their chunk arrived — dropping whole chunks after each
    change cost a second per step.

    Why the *least* delayed chunk, not the newest: what the station reads is late by however long the
    link and the host held it — a UART's transmit queue near its baud, a host busy elsewhere — and that
    lateness comes and goes.  Taken from the newest chunk, "now" on the unit's clock was late by as much,
    and a step's settle began that much too early: on a loaded 38400-baud run, readings and current
    reports from before the load's change were counted at the new level (a good unit FAILed its return
    to zero, its current sensor "28.6 % low").  The smallest lag seen (host arrival less the newest stamp)
    is the closest bound on the clocks' offset: the unit's time then lags the truth only by the link's
    least delay.  (Two crystals drift apart by a few milliseconds over a sweep at most: a clock kept per
    sweep needs no drift term.)"""

    def __init__(self, now: Callable[[], float] = time.monotonic) -> None:
        self.now = now
        self.offset_ms: float | None = None  # host arrival less unit stamp, the smallest seen (ms)
        self._seen: list[tuple[float, float]] = []  # (host arrival, newest stamp) of every chunk (ms)

    def saw(self, chunk: SampleChunk) -> None:
        stamps = [np.max(chunk.t_ms)] if len(chunk.t_ms) else []
        stamps += [np.max(more.t_ms) for more in chunk.more.values() if len(more.t_ms)]
        if chunk.imu is not None and len(chunk.imu.t_ms):
            stamps.append(np.max(chunk.imu.t_ms))
        if stamps:
            host_ms, stamp_ms = self.now() * 1000.0, float(max(stamps))
            offset = host_ms - stamp_ms
            self.offset_ms = offset if self.offset_ms is None else min(self.offset_ms, offset)
            self._seen.append((host_ms, stamp_ms))

    def rate(self) -> float | None:
        """How fast the unit's clock runs against the host's, where it is plainly slower than a crystal's 1.0
        (None: not, or too short a record to tell).  Why: a simulator that keeps lockstep with its feeder runs
        slower than real time on a machine short of CPU (PX4's SITL, with three CPU-bound processes beside it
        on two cores, at 21 % of it); its lag then grows by seconds a step, the least lag ever seen put its
        "now" seconds ahead, and no reading was ever after a step's settle.  Read from the first chunk to the
        newest over at least :data:`RATE_SPAN_S`: a link's lateness moves it by the link's jitter over that
        span, far less than :data:`SLOW_CLOCK`'s margin, so a real board keeps the least lag as above."""
        if len(self._seen) < 2:
            return None
        (h0, s0), (h1, s1) = self._seen[0], self._seen[-1]
        if h1 - h0 < RATE_SPAN_S * 1000.0:
            return None
        rate = (s1 - s0) / (h1 - h0)
        return rate if rate < SLOW_CLOCK else None

    def at_ms(self, host_s: float) -> float:
        """The unit's stamp at the host's time ``host_s`` (−∞ before the first chunk: take everything).  At a
        clock's own :meth:`rate`, the line of that slope on which no stamp seen lies after its arrival."""
        if self.offset_ms is None:
            return float("-inf")
        rate = self.rate()
        if rate is None:
            return host_s * 1000.0 - self.offset_ms
        seen = np.asarray(self._seen)
        return float(np.max(seen[:, 1] - rate * seen[:, 0])) + rate * host_s * 1000.0


# A unit's clock that ran below this share of the host's, over at least RATE_SPAN_S of the host's, is read at its
# own rate (a real board's crystal is within 10⁻⁴ of it; to fake a half over seconds, a link's lateness would grow
# by half of them: a line carrying half the stream, which the sweep refuses when it opens its stream).
SLOW_CLOCK = 0.5
RATE_SPAN_S = 5.0


class LevelKeeper:
    """Sets the source's level, and keeps it drawn however long a step reads: a level that lasts only
    ``level_lasts_s`` once set (a motor test spins for the seconds asked, then the firmware stops it) is
    set again before half of that has passed.  Why: a step reads as long as the noise or the hold asks —
    far longer than a motor test's few seconds — and readings after the motor stopped would be taken at
    idle yet counted at the step's current."""

    def __init__(self, source: CurrentSource) -> None:
        self.source = source
        self.lasts_s: float | None = getattr(source, "level_lasts_s", None)
        self.level: float | None = None
        self.set_at = 0.0

    def set(self, level: float) -> None:
        self.source.set_level(level)
        self.level, self.set_at = level, time.monotonic()

    def __call__(self) -> None:
        if self.lasts_s and self.level is not None and time.monotonic() - self.set_at > self.lasts_s / 2.0:
            self.set(self.level)


def run_sweep(run: RunContext, source: CurrentSource, settings: InterferenceSettings, device_ids: list[int],
              goal: HoldGoal | None = None) -> Sweep:
    """Step the source through :func:`sweep_levels`, reading every compass in ``device_ids`` (the
    primary first) and the unit's current after each settle; with a ``goal`` (a compensated unit), the
    top and the last zero step are held for it (:mod:`.hold`).  The source draws nothing again
    afterwards, whatever happened."""
    started = time.monotonic()
    deadline = started + settings.timeout_s
    steps: list[SweepStep] = []
    clock = UnitClock()
    stream, first, stream_hz = open_stream(run, settings)
    chunks = itertools.chain(first, stream)  # the first chunk, read to open the stream, goes to the first step
    keeper = LevelKeeper(source)
    levels = sweep_levels(settings.steps)
    wanted = settings.readings
    held = asked = 0  # readings held at the ends in all, and what the goal asked there
    # when each step began, before its source was set, and how long it was held: a step's cost is from one
    # step to the next, without its hold
    began: list[float] = []
    hold_s: list[float] = []
    try:
        for index, level in enumerate(levels):
            run.abort.check()
            began.append(time.monotonic())
            hold_s.append(0.0)
            keeper.set(level)
            step = SweepStep(level=level)
            settle_at = clock.now() + settings.settle_s
            step_started = time.monotonic()
            _read_step(chunks, clock, step, settle_at, wanted, device_ids, deadline, keeper)
            while index == 0:  # the compasses' noise at 0 A decides how many readings every step needs,
                # estimated again from each larger set until the readings in hand are enough
                most = readings_in_time(step, device_ids, levels, settings, time.monotonic() - step_started,
                                        deadline - time.monotonic())
                needed = readings_for_target(step, device_ids, levels, run.product.current_max_a or 0.0, settings,
                                             most)
                if needed <= wanted:
                    break
                wanted = needed
                run.log(f"sweep: {wanted} readings a step bring the field per amp to ±"
                        f"{settings.target_sigma_ut_per_a:g} µT/A (the compasses' noise at 0 A)"
                        + (f" — or as near as the sweep's {settings.timeout_s:g} s allow" if wanted == most else ""))
                _read_step(chunks, clock, step, settle_at, wanted, device_ids, deadline, keeper)
            if goal is not None and index in (settings.steps, len(levels) - 1):  # the top, the last zero: hold
                step_s = float(np.max(np.diff(began) - hold_s[:-1]))
                holding = time.monotonic()
                held, asked = _hold(run, (chunks, clock, keeper), step, steps, levels, index, settle_at, wanted,
                                    device_ids, goal, (started, step_started, deadline, step_s, began[0] - started),
                                    held)
                hold_s[-1] = time.monotonic() - holding
            step.source_a = source.measured_current_a()
            steps.append(step)
            run.log(f"sweep {level:.0%}: unit reads {_amps(step.firmware_mean_a)}, source {_amps(step.source_a)}")
    except BaseException:
        # draw nothing whatever happened; a source that fails to stop too must not hide why the sweep failed
        try:
            stream.close()
            source.stop()
        except Exception as exc:
            run.log(f"after the failed sweep, stopping the current source failed too: {exc}")
        raise
    stream.close()
    source.stop()
    return Sweep(steps=steps, seconds=time.monotonic() - started, device_ids=list(device_ids), readings_per_step=wanted,
                 held_readings=held, hold_asked=asked, stream_hz=stream_hz)


def open_stream(run: RunContext, settings: InterferenceSettings) -> tuple[Iterator[SampleChunk], list[SampleChunk],
                                                                           float]:
    """The sweep's stream, its first chunk (read here: a backend checks its line when the stream starts)
    and the rate asked.  ``interference.rate_hz`` where the station file sets it, refused with the figures
    on a serial line too slow for it; unset, :data:`DEFAULT_STREAM_HZ`, lowered once to what a serial
    line carries (logged) — the station's own choice is not the line's fault."""
    dut = run.require_dut()
    try:
        return _first_chunk(dut, settings.rate_hz or DEFAULT_STREAM_HZ)
    except StreamTooFast as exc:
        if settings.rate_hz is not None or exc.fits_hz < LEAST_STREAM_HZ:
            raise
        rate_hz = float(np.floor(exc.fits_hz))
        run.log(f"sweep: the serial line carries the sweep's stream at {rate_hz:g} Hz, not {DEFAULT_STREAM_HZ:g} "
                "(interference.rate_hz unset)")
        return _first_chunk(dut, rate_hz)


def _first_chunk(dut: DutBackend, rate_hz: float) -> tuple[Iterator[SampleChunk], list[SampleChunk], float]:
    stream = dut.samples(rate_hz)
    try:
        return stream, [next(stream)], rate_hz
    except StopIteration:
        raise DutError("the unit's stream ended before the current sweep read anything") from None


def _hold(run: RunContext, reading: tuple, step: SweepStep, steps: list[SweepStep], levels: list[float],
          index: int, settle_at: float, wanted: int, device_ids: list[int], goal: HoldGoal,
          times: tuple[float, float, float, float, float], held: int) -> tuple[int, int]:
    """Hold the top step or the last zero step for :mod:`.hold`'s goal.  The top is held once, for as many
    readings as the plan gives it if the last zero gets as many; the last zero is then planned afresh from
    the whole sweep and from the budget truly left — so the top's plan, made from half a sweep and a few
    readings' timing, never commits the last zero to more than the budget holds — and planned again after
    each hold until the goal is met or the budget ends.  ``reading``: the stream, the unit's clock and the
    level's keeper.  ``times``: when the sweep and this step started,
    the sweep's deadline, the slowest step's cost so far and what opening the sweep's stream cost.
    Returns the readings held at the ends in all, and what the goal asks there in all (as readings at
    both ends: at the top, the plan; at the last zero, what is held plus what both ends would still
    need)."""
    started, step_started, deadline, step_s, opening_s = times
    stream, clock, keeper = reading
    top, last = levels.index(1.0), len(levels) - 1
    sweep_so_far = [*steps, step]
    while True:
        plan = plan_for_goal(sweep_so_far, device_ids, levels, wanted, goal.share)
        both = plan.readings((top, last))
        asked = held + 2 * both  # what the whole sweep needs, as far as it is known now
        if index == top:
            more, ends = both, 2
        else:  # the top is past: only the last zero can still be held
            more, ends = (plan.readings((last,)) if both else 0), 1
        if not more:
            break
        spent = time.monotonic() - started
        slowest = min(len(step.readings.get(d, [])) for d in device_ids)
        reading_s = max(time.monotonic() - step_started - run.station.interference.settle_s, 1e-3) / max(slowest, 1)
        allowed = min(more, readings_in_budget(spent, step_s, last - index, reading_s, goal.budget_s,
                                               deadline - time.monotonic(), ends, opening_s))
        if not allowed:
            run.log(f"sweep {step.level:.0%}: the goal (every compensated slope known to {goal.share:.0%} of itself) "
                    f"asks for more readings at the ends than the {goal.budget_s:g} s budget holds")
            break
        run.log(f"sweep {step.level:.0%}: held for {allowed} readings more, to know every compensated slope to "
                f"{goal.share:.0%} of itself")
        _read_step(stream, clock, step, settle_at, slowest + allowed, device_ids, deadline, keeper)
        held += allowed
        if index == top:
            break  # the last zero plans again from the whole sweep
    return held, asked


def readings_in_time(step: SweepStep, device_ids: list[int], levels: list[float], settings: InterferenceSettings,
                     spent_s: float, left_s: float) -> int:
    """The most readings a step that let the whole sweep end within its timeout, at the rate the slowest
    compass delivered them in this first step (``spent_s`` so far, its settle included; ``left_s`` to
    the deadline), with a fifth of the time spare.  Why: a noisy compass at 10 Hz would otherwise be
    asked for more readings than the timeout holds, and the unit end as the station's ERROR."""
    have = min(len(step.readings.get(d, [])) for d in device_ids)
    reading_s = max(spent_s - settings.settle_s, 1e-3) / max(have, 1)
    later = len(levels) - 1  # the steps still to come, each with its settle
    budget = 0.8 * left_s - later * settings.settle_s
    return max(settings.readings, int((budget / reading_s + have) / len(levels)))


def readings_for_target(step: SweepStep, device_ids: list[int], levels: list[float], top_a: float,
                        settings: InterferenceSettings, most: int | None = None) -> int:
    """Readings a step that bring the slope's 1σ per axis to ``target_sigma_ut_per_a`` for the noisiest
    compass: a line through ``n`` readings at each current ``L·top`` has ``σ_c = σ / (top·√(n·Σ(L − L̄)²))``.
    The noise is each compass's scatter at this (0 A) step, pooled over its three axes, as the fit pools
    the residuals; between ``readings`` and ``readings_max`` (or ``most``, what the time allows)."""
    if top_a <= 0:
        return settings.readings
    spread = float(np.sum((np.asarray(levels) - np.mean(levels)) ** 2))
    noise = 0.0
    for device_id in device_ids:
        fields = step.fields(device_id)
        if len(fields) >= 2:
            noise = max(noise, float(np.sqrt(np.sum(np.var(fields, axis=0, ddof=1)) / 3.0)))
    needed = (noise / (top_a * settings.target_sigma_ut_per_a)) ** 2 / spread
    ceiling = settings.readings_max if most is None else min(settings.readings_max, most)
    return int(min(max(settings.readings, np.ceil(needed)), max(ceiling, settings.readings)))


def _amps(value: float | None) -> str:
    return "—" if value is None else f"{value:.2f} A"


def _read_step(stream, clock: UnitClock, step: SweepStep, settle_at: float, wanted: int, device_ids: list[int],
               deadline: float, keep_level: Callable[[], None] = lambda: None) -> None:
    """Read one step until it holds ``wanted`` readings of every compass and at least one current reading,
    all taken once its level had settled: ``settle_at`` is that moment on the host's clock (``clock.now``),
    turned into the unit's stamp with the unit's clock as known at each chunk.  ``keep_level`` is called at
    every chunk (to keep the step's level drawn).

    Why not decided reading by reading as each arrives: the unit's clock is known only as well as the least
    delayed chunk seen so far.  A link that held the unit's output (a USB bus that stalls, a host that reads
    its port late) delivers what it held at once, every chunk of it late, and the clock is then late by as
    much until a prompt chunk arrives: on it, readings from before a level change were counted at the new
    level (a good unit's current sensor then read 7 % low, its linearity FAILed).  So every reading is kept
    with its stamp and the step's are chosen again at each chunk with the clock as known then; and a step
    cannot end before ``settle_at`` on the host's clock, since nothing taken after it can have arrived
    sooner — by then the chunks that prove the clock have arrived too."""
    settled_at = clock.now()
    unmeasured = 0  # current reports saying "not measured"
    while True:
        if clock.now() > deadline:
            have = ", ".join(f"{d}: {len(step.readings.get(d, []))}" for d in device_ids)
            repeating = [d for d in device_ids if len(step.readings.get(d, [])) < wanted and step.heard.repeats.get(d)]
            why = "" if not repeating else (
                f" — compass {', '.join(map(str, repeating))} sent the same value in every message while the unit "
                "was still: no noise to tell one reading from the next (a stuck sensor, or a simulator's noiseless "
                "compass)")
            raise StationFault(f"the current sweep outlasted its timeout at the {step.level:.0%} step (readings "
                               f"{have}; unit current readings {len(step.firmware_a)}){why}")
        try:
            chunk: SampleChunk = next(stream)
        except StopIteration:
            raise DutError("the unit's stream ended during the current sweep") from None
        clock.saw(chunk)
        keep_level()
        step.heard.add(chunk, device_ids)
        step.settled_from(clock.at_ms(settle_at))
        unmeasured += chunk.current_unmeasured
        if clock.now() < settle_at:
            continue
        compasses_done = all(len(step.readings.get(d, [])) >= wanted for d in device_ids)
        if step.firmware_a and compasses_done:
            return
        if unmeasured and not step.firmware_a and compasses_done:
            raise StationFault(f"the unit does not measure its current: its battery monitor reports the current as "
                               f"not measured ({unmeasured} reports at the {step.level:.0%} step) — no current "
                               "sensor configured on the primary battery monitor (a voltage-only monitor)")
        if compasses_done and clock.now() > settled_at + NO_CURRENT_S:
            raise StationFault(f"the unit reports no current (no BATTERY_STATUS for {NO_CURRENT_S:g} s at the "
                               f"{step.level:.0%} step): no current sensor configured, or no battery monitor")
