"""Per-unit state handed to every phase hook.

Why a context object: hooks get one argument that carries the station, the product, the live DUT
and the listeners, so hook signatures stay stable as phases learn more.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from magline.core.sequencer.periodic import every

if TYPE_CHECKING:
    from magline.core.dut import DutBackend, Magnetometer, UnitInfo
    from magline.core.field import FieldSource
    from magline.core.fit import FitOptions, FitResult
    from magline.core.fit.samples_csv import RawSamples
    from magline.core.interference.model import Interference
    from magline.core.measurements import Numeric
    from magline.core.mounting import ImuSeries
    from magline.core.plugins import Plugins
    from magline.core.power import PowerControl
    from magline.core.record import PersistReport, PhaseResult, RunRecord
    from magline.core.sequencer.abort import AbortSwitch
    from magline.core.sequencer.rounds import MotionRounds
    from magline.core.station.schema import Limit, Product, Station


@dataclass
class Acquisition:
    """One acquisition attempt: distinct raw readings and the coverage they reached.

    ``repeats`` counts the copies of readings the stream carried and the backend dropped (a stream
    faster than the sensor); ``sensor_rate_hz`` is the rate of distinct readings actually received.
    """

    attempt: int
    samples: RawSamples
    coverage: float
    target: float
    repeats: int = 0
    sensor_rate_hz: float | None = None
    # the other magnetometers' readings over the same tumble, by device id, and the accelerometer's
    more: dict[int, RawSamples] = field(default_factory=dict)
    imu: ImuSeries | None = None
    coverages: dict[int, float] = field(default_factory=dict)  # per device id; ``coverage`` is the worst
    # why the tumble ended ("determined", "stalled", "samples": the most asked for, "timeout": a determined
    # tumble out of time with readings enough to judge, "stream ended"), after how
    # long, and the running fit's predicted uncertainties per sensor prefix when it was determined
    stopped: str | None = None
    tumble_s: float | None = None
    predicted: dict[str, dict[str, float]] = field(default_factory=dict)
    advice: str | None = None  # what the operator is told before the next attempt, when the tumble knows why
    stalled_because: str = ""  # a stalled tumble's cause in the log's words (core/acquisition/tumble_stop.py)
    # readings read (held, or let go when a long tumble was thinned; ``samples`` holds at most
    # ``acquisition.samples``): the count the operator was shown, which never goes down
    read: int | None = None

    @property
    def sufficient(self) -> bool:
        return self.coverage >= self.target


class AcquisitionAborted(RuntimeError):
    """An acquisition stopped early (DUT or link failure, operator abort, plugin bug).

    Carries what arrived (``partial``) so the raw data is recorded, and the original exception
    (``cause``), which the sequencer re-raises so the unit is classified by what really happened.
    """

    def __init__(self, partial: Acquisition, cause: BaseException) -> None:
        super().__init__(str(cause))
        self.partial = partial
        self.cause = cause


@dataclass
class RunContext:
    station: Station
    station_dir: Path
    part: str
    product: Product
    serial: str
    operator: str
    plugins: Plugins
    record: RunRecord
    limits: dict[str, Limit]
    reference_field_ut: float | None = None
    field_source: FieldSource | None = None
    dut: DutBackend | None = None
    power: PowerControl | None = None
    unit: UnitInfo | None = None
    attempts: list[Acquisition] = field(default_factory=list)
    # the magnetometers calibrated in this run, primary first (one entry for a one-sensor backend)
    magnetometers: list[Magnetometer] = field(default_factory=list)
    fits: dict[int, FitResult] = field(default_factory=dict)  # by device id, from the accepted attempt
    # why the next acquisition attempt is needed, in the operator's terms (None: low coverage)
    retry_advice: str | None = None
    # what the phases hand on to each other (typed, so a phase cannot miss a key another wrote):
    fit: FitResult | None = None  # the primary's calibration, after the fit phase …
    fit_s: float = 0.0  # … and how long fitting every sensor took
    # the validate phase's mounting check, for the persist phase: firmware orientations to write (device
    # id → orientation value, ``orientation: fix``) and custom rotations (device id → parameters,
    # ``misalignment: write``)
    orientation_fixes: dict[int, int] = field(default_factory=dict)
    rotation_writes: dict[int, dict[str, float]] = field(default_factory=dict)
    # what the line knows of each sensor's time skew (by measurement prefix; None: nothing), found once
    # for the tumble's stop and the mounting check (core/mounting/line_skew.py)
    skew_priors: dict[str, Any] = field(default_factory=dict)
    persisted: PersistReport | None = None  # what the persist phase wrote, for the verify phase
    # the current interference: what draws the sweep's current (opened by the interference
    # phase, closed with the unit) and what the sweep found, for validate, persist and verify
    current_source: Any = None
    interference: Interference | None = None
    phase_started_at: float = 0.0  # time.monotonic() when the running phase began
    # the station's results stores (the sink contract, ``ResultSink``): what listeners read back — the
    # process's history for the in-run review, the stored record for a report
    results: Any = None
    state: dict[str, Any] = field(default_factory=dict)  # scratch space for plugins only
    abort: AbortSwitch | None = None
    slot: str | None = None  # the fixture position on a station with slots (None: a one-unit station)
    rounds: MotionRounds | None = None  # the motion this unit shares (see core/sequencer/rounds)
    _phase: PhaseResult | None = None

    @contextmanager
    def shared_motion(self) -> Iterator[int | None]:
        """Around the reading of one attempt: waits for the shared motion's next round (the slots
        that need samples lined up, the fixture moving) and yields its number; leaving the block
        tells the motion this unit has its samples."""
        if self.rounds is None:
            yield None
            return
        with self.rounds.shared_round(self.slot or "", self.check_abort) as number:
            yield number

    def check_abort(self) -> None:
        """A safe point in a long loop: raise :class:`~magline.core.faults.UnitAborted` when the
        operator asked to stop (an abort requested from another thread lands here)."""
        if self.abort is not None:
            self.abort.check()

    def log(self, message: str) -> None:
        """Add a line to the current phase's log (kept in the record)."""
        if self._phase is not None:
            self._phase.log.append(message)

    def prompt(self, message: str) -> None:
        self.log(f"operator: {message}")
        self.plugins.hook.magline_operator_prompt(run=self, message=message)

    def confirm(self, question: str, timeout_s: float) -> bool | None:
        """The operator's yes or no to ``question`` (None: nobody could be asked); logged either way."""
        self.log(f"operator asked: {question}")
        answer = self.plugins.hook.magline_operator_confirm(run=self, question=question, timeout_s=timeout_s)
        self.log(f"operator answered: {'nobody' if answer is None else 'yes' if answer else 'no'}")
        return answer

    @contextmanager
    def waiting(self, what: str, limit_s: float | None = None, tick_s: float = 1.0) -> Iterator[None]:
        """Around a long blocking wait: ``magline_waiting`` about every ``tick_s`` from a timer thread,
        then ``magline_wait_ended`` once.  The lock makes the end final: a tick that was under way when
        the wait ended finishes first, and none comes after the end."""
        started = time.monotonic()
        lock = threading.Lock()
        over = False

        def tick() -> None:
            with lock:
                if not over:
                    self.plugins.hook.magline_waiting(run=self, what=what, elapsed_s=time.monotonic() - started,
                                                      limit_s=limit_s)

        try:
            with every(tick_s, tick, "magline-countdown"):
                yield
        finally:
            with lock:
                over = True
            self.plugins.hook.magline_wait_ended(run=self, what=what, waited_s=time.monotonic() - started)

    def acquisition_stopped(self, result: Acquisition) -> None:
        """The tumble of an attempt ended: say why and when to the log and to every listener."""
        read = result.read if result.read is not None else len(result.samples)
        kept = f" ({len(result.samples)} kept)" if read != len(result.samples) else ""
        if result.stopped == "determined":
            worst = max(result.predicted.values(), key=lambda f: f.get("direction_sigma_deg", 0.0), default={})
            self.log(f"determined after {result.tumble_s:.1f} s: {read} readings{kept}, predicted heading "
                     f"σ {worst.get('direction_sigma_deg', float('nan')):.2f}°")
        elif result.stopped == "samples":
            self.log(f"tumble ended at {read} readings{kept} after {result.tumble_s:.1f} s")
        elif result.stopped == "stalled":
            self.log(f"tumble stalled after {result.tumble_s:.1f} s: {read} readings{kept}, "
                     f"{result.stalled_because or 'no new direction lately'}")
        elif result.stopped == "timeout":
            self.log(f"tumble out of time after {result.tumble_s:.1f} s: {read} readings{kept}")
        self.plugins.hook.magline_acquisition_stopped(run=self, attempt=result.attempt, reason=result.stopped or "",
                                                      after_s=result.tumble_s or 0.0, readings=read,
                                                      predicted=dict(result.predicted))

    def progress(self, attempt: int, samples: int, coverage: float, target: float,
                 bins: Sequence[int] | None = None, n_bins: int | None = None) -> None:
        self.plugins.hook.magline_acquisition_progress(run=self, attempt=attempt, samples=samples,
                                                       coverage=coverage, target=target,
                                                       bins=None if bins is None else [int(b) for b in bins],
                                                       n_bins=n_bins)

    def require_power(self) -> PowerControl:
        if self.power is None:
            raise RuntimeError("no power control is set up")
        return self.power

    def fit_options(self, sensor: Magnetometer | None = None) -> FitOptions:
        """The fit's settings for a sensor (the primary by default): clipping is judged against the
        station's ``range_ut``, else the range the backend says the sensor's readings can carry.

        The fit refuses a calibration its readings leave less determined than the station's
        ``direction_sigma_deg`` limit for the sensor (when below the fit's own bound): that is a
        tumble that did not determine the calibration — asked again, as too little coverage is —
        not a unit judged bad.  A good compass whose determined tumble reached its most readings at
        σ 0.50° was FAILed on that limit (issue 28's false-reject benchmark)."""
        from magline.core.fit import FitOptions
        from magline.core.measurements import limit_for

        model = self.product.soft_iron_model
        if model == "auto":
            model = self.unit.soft_iron_model if self.unit else "full"
        sensor = sensor or (self.magnetometers[0] if self.magnetometers else None)
        acq = self.station.acquisition
        bound = self.station.fit.max_direction_sigma_deg
        limit = limit_for((self.sensor_prefix(sensor.device_id) if sensor else "") + "direction_sigma_deg", self.limits)
        if limit is not None and limit.high is not None:
            bound = min(bound, limit.high)
        return FitOptions(model=model, field_ut=self.reference_field_ut,
                          range_ut=acq.range_ut or (sensor.range_ut if sensor else None),
                          coverage_bins=acq.coverage_bins, gain_sigma=self.station.fit.gain_sigma,
                          max_direction_sigma_deg=bound,
                          sample_rate_hz=sensor.averaged_sample_hz if sensor else 0.0)

    @property
    def unit_moves(self) -> bool:
        """Whether the station turns the unit (a tumble) or the field round it (a field source with
        ``moves_unit = False``, a coil): what the operator is told when the acquisition ends."""
        return bool(getattr(self.field_source, "moves_unit", True))

    def sensor_prefix(self, device_id: int) -> str:
        """The measurement-name prefix of a sensor: ``""`` for the primary, ``mag2.`` for the second…"""
        ids = [m.device_id for m in self.magnetometers]
        position = ids.index(device_id) if device_id in ids else 0
        return "" if position == 0 else f"mag{position + 1}."

    def sensor_label(self, device_id: int) -> str:
        """How the operator is told which sensor: the firmware's name and its device id."""
        for m in self.magnetometers:
            if m.device_id == device_id:
                return f"{m.label} ({device_id})"
        return f"magnetometer {device_id}"

    def plugin_options(self, section: str) -> Any:
        """The station file's ``plugins.<section>``, validated by the model its plugin registered
        (``magline_register_plugin_options``); None when the station file has no such section."""
        raw = self.station.plugins.get(section)
        if raw is None:
            return None
        return self.plugins.options("plugin options", section, raw, f"plugins.{section}", self.station_dir)

    def measured(self, name: str, value: float) -> Numeric:
        """A plugin's own measurement (declared with ``magline_register_measurements``; a sensor's with its
        prefix, ``mag2.<name>``) judged against the station's limit for it, in its declared unit."""
        from magline.core.measurements import Numeric, base_name

        declared = self.plugins.measurements.get(base_name(name))
        if declared is None:
            raise ValueError(f"measurement {name!r} is not declared: a plugin declares its own measurements with "
                             "the magline_register_measurements hook")
        return Numeric.of(name, value, self.limits, unit=declared.unit)

    def require_unit(self) -> UnitInfo:
        if self.unit is None:
            raise RuntimeError("the unit has not been identified")
        return self.unit

    def require_fit(self) -> FitResult:
        if self.fit is None:
            raise RuntimeError("nothing is fitted yet")
        return self.fit

    def require_dut(self) -> DutBackend:
        if self.dut is None:
            raise RuntimeError("no DUT is connected")
        return self.dut
