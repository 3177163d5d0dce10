"""The tumble's side of a turntable round (:mod:`magline.core.motion.guided`): what each slot hands the
guide at every chunk — its unit's gravity and whether it is still, its coverage, its sensor's mounting —
and what it passes on: the words to the operator and the picture for the console and the screen
(``magline_tilt_guidance``)."""

from __future__ import annotations

from collections import deque
from typing import TYPE_CHECKING

import numpy as np

from magline.core.dut import SampleChunk
from magline.core.motion import TurnsForTilts
from magline.core.motion.guided import Guidance, TiltGuide
from magline.core.mounting.checks import configured_rotation

if TYPE_CHECKING:
    from magline.core.sequencer.context import RunContext

WINDOW_MS = 400.0  # the accelerometer's readings a tilt is judged on
STEADY_DEG = 4.0  # a unit whose gravity wanders less than this over the window is held still


def tilt_guide(run: RunContext, number: int | None, n_bins: int) -> TiltGuide | None:
    """The round's guide when the station's motion is a turntable (None otherwise)."""
    rounds = run.rounds
    motion = getattr(rounds, "motion", None)
    if rounds is None or number is None or not isinstance(motion, TurnsForTilts):
        return None
    inclination = getattr(run.field_source, "reference_inclination_deg", lambda: None)()
    return rounds.guide(number, lambda members: TiltGuide(motion, members, n_bins, inclination))


class GravityWindow:
    """The unit's latest accelerometer readings (``WINDOW_MS`` of them): their mean and whether it held still."""

    def __init__(self) -> None:
        self.rows: deque[tuple[float, np.ndarray]] = deque()

    def add(self, chunk: SampleChunk) -> None:
        if chunk.imu is None or not len(chunk.imu):
            return
        for t, a in zip(np.asarray(chunk.imu.t_ms, float), np.asarray(chunk.imu.accel_mss, float), strict=True):
            self.rows.append((float(t), a))
        latest = self.rows[-1][0]
        while self.rows and self.rows[0][0] < latest - WINDOW_MS:
            self.rows.popleft()

    def latest(self) -> tuple[np.ndarray | None, bool]:
        if not self.rows:
            return None, False
        rows = np.array([a for _, a in self.rows])
        mean = rows.mean(axis=0)
        unit = rows / np.maximum(np.linalg.norm(rows, axis=1, keepdims=True), 1e-9)
        spread = np.degrees(np.arccos(np.clip(unit @ (mean / max(np.linalg.norm(mean), 1e-9)), -1.0, 1.0)))
        return mean, len(rows) >= 3 and float(spread.max()) < STEADY_DEG


class Guiding:
    """One slot's acquisition under a turntable guide."""

    def __init__(self, run: RunContext, guide: TiltGuide) -> None:
        self.run, self.guide = run, guide
        self.gravity = GravityWindow()
        self.turning_seen = 0  # readings received while the table turned: what a stall is counted in
        self.last: dict | None = None
        sensors = run.magnetometers
        self.sensor_to_body = configured_rotation(sensors[0]) if sensors else np.eye(3)

    def ended(self) -> None:
        """This slot's tumble is over (determined, stalled, aborted): the cradle's words pass to the next."""
        self.guide.leave(self.run.slot or "")

    def step(self, chunk: SampleChunk, taken: int, bins: np.ndarray) -> Guidance:
        self.gravity.add(chunk)
        gravity, steady = self.gravity.latest()
        board_ms = float(chunk.t_ms[-1]) if len(chunk.t_ms) else None
        guidance = self.guide.step(self.run.slot or "", gravity, steady, set(int(b) for b in bins),
                                   self.sensor_to_body, board_ms)
        if guidance.state == "turning":
            self.turning_seen += taken
        if guidance.prompt:
            self.run.prompt(guidance.prompt)
        shown = guidance.to_dict()
        if shown != self.last:
            self.last = shown
            self.run.plugins.hook.magline_tilt_guidance(run=self.run, guidance=shown)
        return guidance
