"""The fit that runs beside a tumble, and the rule that says the tumble has determined the calibration.

Why: a line is paid by the second, and a fixed sample count is either too many (a fast sensor on a
good tumble, already determined after a few seconds) or too few.  The fit knows its own
uncertainty, so the tumble can end the moment every magnetometer's predicted σ is inside the
station's limits with a margin and the coverage target is met, never before ``min_samples``.

The fits run on a worker thread, on snapshots of what arrived so far: the stream keeps being read
while a fit runs (nothing is dropped, nothing waits), and a snapshot that arrives while the worker
is busy replaces the one waiting, so the worker always fits the newest readings.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from magline.core.fit.result import FitRefused, FitResult
from magline.core.fit.samples_csv import RawSamples

# The predicted uncertainties a station's limits can hold, each read off a fit the same way the
# validate phase measures it.
PREDICTED: dict[str, Callable[[FitResult], float]] = {
    "direction_sigma_deg": lambda fit: float(fit.direction_sigma_deg),
    "hard_iron_sigma_ut": lambda fit: float((fit.hard_iron_sigma_ut ** 2).sum() ** 0.5),
    # how large a warm-up drift could pass the drift test unseen (not judged, or no time stamps: unknown)
    "drift_detectable_ut": lambda fit: float((fit.drift or {}).get("detectable_ut", float("inf"))),
}


@dataclass(frozen=True)
class StopRule:
    """When a tumble has determined the calibration: every sensor's coverage at its target, each
    predicted σ at most ``margin`` × its limit, and its warm-up drift test able to judge (on a sweep
    that has not yet turned back, a drift is indistinguishable from soft iron), after at least
    ``min_samples`` readings.

    ``limits``: per sensor (its measurement prefix, ``""`` for the primary, ``mag2.``…) the upper
    limit of each of :data:`PREDICTED` the station holds for it; ``coverage``: per sensor, the
    coverage it needs where more than ``coverage_target`` (a ``coverage`` limit of the station);
    ``wait_for_drift_test``: False stops without the drift test's judgement (a line of warm units)."""

    min_samples: int
    coverage_target: float
    margin: float
    limits: Mapping[str, Mapping[str, float]]
    coverage: Mapping[str, float] = field(default_factory=dict)
    wait_for_drift_test: bool = True

    def targets(self, sensor: str) -> dict[str, float]:
        return {name: self.margin * limit for name, limit in self.limits.get(sensor, {}).items()}

    def judge(self, fits: Mapping[str, FitResult]) -> dict[str, dict[str, float]] | None:
        """Every sensor's predicted figures when each meets its targets, else None."""
        predicted: dict[str, dict[str, float]] = {}
        for sensor, fit in fits.items():
            if fit.coverage < max(self.coverage_target, self.coverage.get(sensor, 0.0)):
                return None
            if self.wait_for_drift_test and _drift_open(fit):
                return None  # a warm-up drift could not yet be told from the calibration, or not be removed
            figures = {name: read(fit) for name, read in PREDICTED.items()}
            if any(not figures[name] <= target for name, target in self.targets(sensor).items()):
                return None
            predicted[sensor] = {name: value for name, value in figures.items() if math.isfinite(value)}
        return predicted


def _drift_open(fit: FitResult) -> bool:
    """The fit's warm-up drift test is still open: it could not judge the readings, or a drift it
    found could be neither set aside nor modelled (``unresolved``)."""
    return fit.drift is not None and (not fit.drift.get("judged", True) or bool(fit.drift.get("unresolved")))


@dataclass
class Determination:
    """The running fit's answer: the tumble is determined after ``readings`` of the primary, at
    ``after_s`` seconds of tumbling, with these predicted figures per sensor."""

    readings: int
    after_s: float
    predicted: dict[str, dict[str, float]] = field(default_factory=dict)


# After each snapshot of a live tumble, the worker rests this many times as long as the snapshot's fits
# took before it takes the next: the fits then hold at most half of a core.  Why: they share the
# interpreter with the thread reading the stream and with the station's screen, and on a station PC
# with two cores a worker fitting back to back took the time those need (a link's heartbeat read late
# is a link lost).  The stop comes at most one fit later than it could; a tumble in simulated time,
# whose offerer waits for each answer, is not paced.
REST_PER_FIT = 1.0

Fitter = Callable[[str, RawSamples], FitResult]
# After the fits met the rule: what else must be determined before the tumble may end (the mounting),
# given the fits, the snapshot and the accelerometer's readings; more predicted figures per sensor,
# or None while not yet determined.
Confirm = Callable[[dict[str, FitResult], dict[str, RawSamples], Any], "dict[str, dict[str, float]] | None"]


class RunningFit:
    """Fits snapshots of the tumble on a worker thread until one is determined.

    ``fitter(sensor, samples)`` is the station's fit (the same engine as the final one);
    ``confirm`` (optional) judges what the fits alone do not (see :data:`Confirm`); ``offer`` hands
    over a snapshot without waiting; ``determined`` is set once a snapshot met the rule.  Use as a
    context manager: leaving stops the worker (a fit under way finishes on its own, its answer
    ignored)."""

    def __init__(self, rule: StopRule, fitter: Fitter, confirm: Confirm | None = None) -> None:
        self.rule = rule
        self.fitter = fitter
        self.confirm = confirm
        self.determined: Determination | None = None
        self.fits_run = 0
        self.last_error: str | None = None  # the last snapshot's refusal (said only when asked)
        self._pending: tuple[int, float, dict[str, RawSamples], Any] | None = None
        self._cond = threading.Condition()
        self._closed = False
        self._busy = False
        self._awaited = False  # the pending snapshot's offerer waits for its answer (simulated time)
        self.fit_s = 0.0  # how long the last snapshot's fits took
        self._thread = threading.Thread(target=self._work, name="magline-running-fit", daemon=True)

    def __enter__(self) -> RunningFit:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    @property
    def idle(self) -> bool:
        """Nothing waiting and nothing being fitted: a new snapshot would be fitted at once."""
        with self._cond:
            return self._pending is None and not self._busy

    def offer(self, readings: int, after_s: float, snapshot: dict[str, RawSamples], wait: bool = False,
              imu: Any = None) -> None:
        """The tumble so far (``readings`` of the primary, ``after_s`` seconds in), by sensor name,
        with the accelerometer's readings (``imu``) for ``confirm``.

        ``wait``: return only once this snapshot is judged.  For a stream that runs ahead of real
        time (a replay, a simulator in simulated time) waiting costs no reading, and it makes the
        stop the same on any machine; a live stream never waits."""
        if readings < self.rule.min_samples or self.determined is not None:
            return
        with self._cond:
            self._pending = (readings, after_s, snapshot, imu)
            self._awaited = wait
            self._cond.notify_all()
            while wait and (self._pending is not None or self._busy) and not self._closed:
                self._cond.wait()

    def _work(self) -> None:
        # The fit imports scipy's optimiser and special functions on first use (kept out of every CLI
        # start): paid here while the tumble begins, not by the first snapshot.
        import scipy.optimize
        import scipy.special  # noqa: F401

        while True:
            with self._cond:
                while self._pending is None and not self._closed:
                    self._cond.wait()
                if self._closed:
                    return
                readings, after_s, snapshot, imu = self._pending
                self._pending = None
                self._busy = True
                paced = not self._awaited
            started = time.monotonic()
            try:
                self._judge(readings, after_s, snapshot, imu)
            finally:
                with self._cond:
                    self._busy = False
                    self._cond.notify_all()
                    if paced and self.determined is None:
                        self._rest(REST_PER_FIT * (time.monotonic() - started))

    def _rest(self, seconds: float) -> None:
        """Let the next snapshot wait ``seconds`` (called holding the condition; a close ends it)."""
        until = time.monotonic() + seconds
        while not self._closed and (left := until - time.monotonic()) > 0:
            self._cond.wait(left)

    def confirm_now(self, readings: int, after_s: float, snapshot: dict[str, RawSamples],
                    imu: Any = None) -> Determination | None:
        """Judge the whole tumble so far on the caller's thread, once a snapshot was determined.

        Why: the readings that arrived while the snapshot was fitted change the fit a little — and
        near a statistical threshold (the warm-up drift test) a little can flip a decision.  The
        tumble ends only when the readings it ends with are determined, so the final fit (the same
        code on the same readings) is the prediction.  Not determined: the tumble goes on."""
        found = self.determined
        if found is not None and found.readings == readings:
            return found  # the snapshot was already every reading (a stream in simulated time waited for it)
        self.determined = None  # the worker may still answer an older snapshot: asked again next time
        return self._judge(readings, after_s, snapshot, imu)

    def awaits_drift_test(self, snapshot: dict[str, RawSamples]) -> bool:
        """Whether the stop still waits for the warm-up drift test on these readings (fitted on the
        caller's thread): some sensor's test cannot yet judge them.  Asked at the count's end, where
        the worker's last snapshot may be older than the readings, or not yet fitted at all (the
        coverage reached its target just before).  A refused fit does not wait: its refusal is the
        final fit's to say."""
        if not self.rule.wait_for_drift_test:
            return False
        try:
            fits = [self.fitter(sensor, samples) for sensor, samples in snapshot.items()]
        except Exception:
            return False
        return any(_drift_open(fit) for fit in fits)

    def _judge(self, readings: int, after_s: float, snapshot: dict[str, RawSamples], imu: Any) -> Determination | None:
        fits: dict[str, FitResult] = {}
        started = time.monotonic()
        try:
            for sensor, samples in snapshot.items():
                fits[sensor] = self.fitter(sensor, samples)
        except FitRefused as exc:  # not determined yet: the next snapshot may be
            self.last_error = exc.message
            return None
        except Exception as exc:  # a fit that crashes here crashes the final fit too, which says it
            self.last_error = f"{type(exc).__name__}: {exc}"
            return None
        finally:
            self.fits_run += 1
            self.fit_s = time.monotonic() - started
        predicted = self.rule.judge(fits)
        if predicted is None:
            return None
        if self.confirm is not None:
            try:
                more = self.confirm(fits, snapshot, imu)
            except Exception as exc:  # the validate phase meets the same fault and says it
                self.last_error = f"{type(exc).__name__}: {exc}"
                return None
            if more is None:
                return None
            for sensor, figures in more.items():
                predicted.setdefault(sensor, {}).update(figures)
        self.determined = Determination(readings=readings, after_s=after_s, predicted=predicted)
        return self.determined
