"""The ``helmholtz`` field source: a 3-axis coil that applies known field vectors to a unit standing still.

Before the shift (the first unit): the coil is energised at full field and must be stable over
``warmup_s`` (warm-up check), the ambient field is nulled in closed loop with the fluxgate at the
centre, and each axis is verified against the fluxgate at ``field_ut``.  A failed check stops the
batch with the figures; an instrument that fails errors the unit with its own message.  The coil
is switched off at the end of every unit, also after errors.
"""

from __future__ import annotations

import threading
import time
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from magline.plugin import FieldSourceError, Fluxgate, fibonacci_sphere
from magline.plugins.helmholtz.coil import CoilDriver
from magline.plugins.helmholtz.shared import SharedSchedule

if TYPE_CHECKING:
    from magline.plugins.helmholtz.options import HelmholtzOptions

AXES = np.eye(3)


def schedule(options: HelmholtzOptions) -> NDArray:
    """Applied vectors: the zero-field steps (they pin the offset), then well spread directions at
    ``field_ut`` in an order where every beginning of the schedule is itself well spread.

    Why that order: a unit may leave the schedule as soon as its calibration is determined
    (``acquisition.stop: determined``), and what it saw must span the sphere then; and a coil that
    drifts a little during the schedule does not turn the drift into an offset along one axis, as a
    pole-to-pole order did."""
    return np.vstack([np.zeros((options.zero_steps, 3)), spread_order(fibonacci_sphere(options.directions))
                      * options.field_ut])


def applied_share(applied_ut: NDArray, steps: NDArray) -> float:
    """The share of the schedule's field directions (its non-zero steps) among the applied vectors:
    a coil unit's coverage, the figure its progress shows and its ``coverage`` measurement keeps."""
    directions = [s for s in np.asarray(steps, float) if np.linalg.norm(s) > 0]
    if not directions:
        return 1.0
    seen = {tuple(v) for v in np.round(np.asarray(applied_ut, float), 6)}
    return sum(tuple(d) in seen for d in np.round(np.asarray(directions), 6)) / len(directions)


def applied_bins(applied_ut: NDArray, directions: int) -> list[int]:
    """The schedule's field directions applied so far, as indices into ``fibonacci_sphere(directions)``
    (the schedule is made of those points): what an operator screen lights up on its sphere."""
    centres = fibonacci_sphere(directions)
    seen = np.asarray(applied_ut, float)
    seen = seen[np.linalg.norm(seen, axis=1) > 0]
    if not len(seen):
        return []
    cos = (seen / np.linalg.norm(seen, axis=1, keepdims=True)) @ centres.T
    return sorted({int(i) for i in np.argmax(cos, axis=1)})


def spread_order(directions: NDArray) -> NDArray:
    """The directions reordered farthest first: each next one the farthest from all before it."""
    left = list(range(len(directions)))
    order = [left.pop(0)]
    while left:
        closest = np.max(directions[left] @ directions[order].T, axis=1)  # cos to the nearest one taken
        order.append(left.pop(int(np.argmin(closest))))
    return directions[order]


class HelmholtzField:
    moves_unit = False  # the unit stands still while the field turns: nobody is told to stop moving it

    def __init__(self, options: HelmholtzOptions, sleep=time.sleep) -> None:
        self.opts = options
        self.sleep = sleep
        self._coil: CoilDriver | None = None
        self._fluxgate: Fluxgate | None = None
        self.ready = False
        self.shift_report: dict[str, Any] = {}
        self._schedules: dict[int, SharedSchedule] = {}  # acquisition round → the schedule its units share
        self._schedules_lock = threading.Lock()
        self.coil_lock = threading.RLock()  # one command sequence at a time on the coil's instruments

    def shared_schedule(self, round_number: int, members: list[str], steps: NDArray) -> SharedSchedule:
        """The schedule of this round of the station's motion, made by the first unit to ask."""
        with self._schedules_lock:
            for number in [n for n, s in self._schedules.items() if s.done]:
                del self._schedules[number]
            if round_number not in self._schedules:
                self._schedules[round_number] = SharedSchedule(self.coil, steps, members, self.coil_lock)
            return self._schedules[round_number]

    @property
    def coil(self) -> CoilDriver:
        """Opened on first use, so an instrument that does not answer errors a unit, not the start-up."""
        if self._coil is None:
            self._coil = CoilDriver(self.opts)
        return self._coil

    @property
    def fluxgate(self) -> Fluxgate:
        if self._fluxgate is None:
            self._fluxgate = Fluxgate(self.opts.reference)
        return self._fluxgate

    def reference_field_ut(self) -> float:
        if not self.ready:
            self.prepare_shift()
        return self.opts.field_ut

    # ------------------------------------------------------------------ before the shift
    def prepare_shift(self) -> None:
        self._warm_up()
        self._null_ambient()
        self._verify_axes()
        self.ready = True

    def _warm_up(self) -> None:
        self.coil.apply(AXES[0] * self.opts.field_ut)
        self.sleep(self.opts.settle_s)
        first = self.fluxgate.read_ut()
        self.sleep(self.opts.warmup_s)
        second = self.fluxgate.read_ut()
        change = float(np.linalg.norm(second - first))
        self.shift_report["warmup_change_ut"] = change
        if change > self.opts.warmup_limit_ut:
            raise FieldSourceError(f"coil not warmed up: the field at {self.opts.field_ut:g} µT changed by "
                                   f"{change:.3f} µT in {self.opts.warmup_s:g} s "
                                   f"(limit {self.opts.warmup_limit_ut:g} µT) — keep it energised longer "
                                   "before the shift")

    def _null_ambient(self) -> None:
        """Closed loop: command zero field, read what is left, fold it into the ambient estimate."""
        self.coil.ambient_ut = np.zeros(3)
        residual = np.full(3, np.inf)
        for _ in range(self.opts.null_iterations):
            self.coil.apply(np.zeros(3))
            self.sleep(self.opts.settle_s)
            residual = self.fluxgate.read_ut()
            if np.linalg.norm(residual) <= self.opts.null_tolerance_ut:
                break
            self.coil.ambient_ut = self.coil.ambient_ut + residual
        left = float(np.linalg.norm(residual))
        self.shift_report |= {"ambient_ut": self.coil.ambient_ut.tolist(), "null_residual_ut": left}
        if left > self.opts.null_tolerance_ut:
            raise FieldSourceError(f"ambient field not nulled: {left:.3f} µT left after {self.opts.null_iterations} "
                                   f"iterations (tolerance {self.opts.null_tolerance_ut:g} µT)")

    def _verify_axes(self) -> None:
        errors = []
        for axis, name in zip(AXES, "xyz", strict=True):
            self.coil.apply(axis * self.opts.field_ut)
            self.sleep(self.opts.settle_s)
            got = float(self.fluxgate.read_ut() @ axis)
            pct = (got / self.opts.field_ut - 1.0) * 100.0
            self.shift_report[f"verify_{name}_pct"] = pct
            if abs(pct) > self.opts.verify_tolerance_pct:
                errors.append(f"axis {name} gives {got:.2f} µT for {self.opts.field_ut:g} µT ({pct:+.2f} %)")
        if errors:
            raise FieldSourceError("coil field verification failed: " + "; ".join(errors) +
                                   f" (tolerance ±{self.opts.verify_tolerance_pct:g} %) — check the coil constants")

    # ------------------------------------------------------------------ per unit
    def finish_unit(self) -> None:
        """Off after each unit — unless other units in the coil are still in their schedule."""
        with self._schedules_lock:
            busy = any(not s.done for s in self._schedules.values())
        if self._coil is not None and not busy:
            with self.coil_lock:
                self._coil.off()

    def close(self) -> None:
        try:
            self.finish_unit()
        finally:
            for instrument in (self._coil, self._fluxgate):
                if instrument is not None:
                    instrument.close()
