"""How long a compensated unit's sweep holds its top step and its last zero step: until every compass's
field per amp is known to the station's ``compensation_goal_pct`` *of itself*, as far as the unit's
``compensation_budget_s`` allows.

Why relative to the compass's own slope: compensation writes the slope found, so what it leaves is that
slope's error.  The station's ``target_sigma_ut_per_a`` is one figure for every compass, but a compass
on a GPS mast that sees 0.03 µT/A must have its slope known ten times more finely than one on the board
at 0.3 µT/A for compensation to leave it the same share.

Why the two ends: a reading adds ``(I − Ī)²`` to the slope's leverage — about ``(top/2)²`` at either end
of the line, next to nothing at half the top — so holding the ends is the cheapest way to know a slope.

Why a budget: a line has its takt.  A compass too slow or too noisy for its goal within the budget is
compensated as well as the budget allows, and the record says how well (``known_pct``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from magline.core.faults import StationFault
from magline.core.interference.line import line_fit

if TYPE_CHECKING:
    from magline.core.interference.sweep import SweepStep

GOAL_SIGMAS = 3.0  # the goal is held by the slope's 3σ per axis: its error's length is within it for 97 % of compasses
# A slope whose square is under this many of its σ² removes less than writing it adds (its error's mean square is
# 3σ², what is left unwritten |c|² ≈ |ĉ|² − 3σ²): such a compass is not compensated, and not held for
WORTH_WRITING_SIGMAS2 = 6.0
PROOF_STEPS = 3  # the proof sweep after the power cycle: 0, top, 0 — it shares the budget
MOST_READINGS = 1_000_000  # a search bound, far beyond any budget


@dataclass(frozen=True)
class HoldGoal:
    """What a compensated unit's sweep holds its ends for: each compass's slope known to ``share`` of
    itself (3σ), the sweep and its proof within ``budget_s``."""

    share: float
    budget_s: float


def leverage(levels: Sequence[float], counts: Sequence[int]) -> float:
    """``Σ n·(L − L̄)²`` over the steps (their currents, or their levels as shares of the top; ``n``
    readings each)."""
    level = np.asarray(levels, float)
    n = np.asarray(counts, float)
    if n.sum() <= 0:
        return 0.0
    mean = float((n * level).sum() / n.sum())
    return float((n * (level - mean) ** 2).sum())


def worth_writing(slope_length: float, sigma_per_axis: float) -> bool:
    """Whether writing a slope ``|ĉ|`` known to ``σ`` per axis removes more than it adds, on average."""
    return slope_length**2 > WORTH_WRITING_SIGMAS2 * sigma_per_axis**2


def known_pct(slope_length: float, sigma_per_axis: float) -> float:
    """How well a written slope is known, as a share of itself: ``3σ / |c|`` in % (∞ for no slope)."""
    return float("inf") if slope_length <= 0 else GOAL_SIGMAS * sigma_per_axis / slope_length * 100.0


def needed_leverage(noise: float, slope_length: float, goal_share: float) -> float:
    """The leverage (in the slope's current units, squared) that brings a slope's σ per axis,
    ``noise / √leverage``, down to ``goal_share · |c| / 3`` (∞ for no slope)."""
    if slope_length <= 0:
        return float("inf")
    return (GOAL_SIGMAS * noise / (goal_share * slope_length)) ** 2


def readings_to_add(levels: Sequence[float], counts: Sequence[int], ends: tuple[int, ...], needed: float) -> int:
    """The fewest readings ``m`` which, added at each of ``ends`` (indices into ``levels``), bring the
    leverage to ``needed``; :data:`MOST_READINGS` if none do."""
    def reached(m: int) -> bool:
        more = list(counts)
        for end in ends:
            more[end] += m
        return leverage(levels, more) >= needed

    if reached(0):
        return 0
    if not reached(MOST_READINGS):
        return MOST_READINGS
    low, high = 0, MOST_READINGS  # reached(high), not reached(low)
    while high - low > 1:
        middle = (low + high) // 2
        low, high = (low, middle) if reached(middle) else (middle, high)
    return high


@dataclass(frozen=True)
class GoalPlan:
    """What the goal needs of the sweep as read so far: the leverage that knows every compass worth
    compensating to its goal, and the sweep's currents and readings per step (those to come at their
    level of the top current read, ``wanted`` readings each)."""

    currents: list[float]
    counts: list[int]
    needed: float

    def readings(self, ends: tuple[int, ...]) -> int:
        """The readings to add at each of ``ends`` (indices into the levels) for the goal; 0 when it is met,
        :data:`MOST_READINGS` if no number there does (readings at one end alone can only bring the
        leverage to ``Σ n·I²``)."""
        return readings_to_add(self.currents, self.counts, ends, self.needed) if self.needed else 0


def plan_for_goal(steps: Sequence[SweepStep], device_ids: Sequence[int], levels: Sequence[float], wanted: int,
                  goal_share: float) -> GoalPlan:
    """The goal's plan from ``steps`` read so far: each compass's line fitted as the analysis fits the
    written slope — its raw readings against the unit's own current per step — so that once nothing more
    is asked, the record's ``known_pct`` is within the goal.  A compass whose slope is still within its
    noise would not be written, so it asks for nothing; nor does a sweep whose unit current did not move
    (the analysis says why)."""
    read_a = [step.firmware_mean_a for step in steps]
    counts = [min(len(step.readings.get(d, [])) for d in device_ids) for step in steps]
    counts += [wanted] * (len(levels) - len(steps))
    if any(a is None for a in read_a):
        return GoalPlan(currents=[], counts=counts, needed=0.0)
    top_a = max(read_a)
    currents = [*read_a, *(level * top_a for level in levels[len(steps):])]
    needed = 0.0
    for device_id in device_ids:
        x = np.concatenate([[a] * len(step.readings.get(device_id, [])) for step, a in zip(steps, read_a, strict=True)])
        y = np.vstack([step.fields(device_id) for step in steps])
        try:
            _, slope, sigma = line_fit(x, y)
        except StationFault:
            return GoalPlan(currents=currents, counts=counts, needed=0.0)
        length = float(np.linalg.norm(slope))
        if not worth_writing(length, float(sigma[0])):
            continue
        noise = float(sigma[0]) * float(np.sqrt(np.sum((x - x.mean()) ** 2)))
        needed = max(needed, needed_leverage(noise, length, goal_share))
    return GoalPlan(currents=currents, counts=counts, needed=needed)


def readings_in_budget(spent_s: float, step_s: float, later: int, reading_s: float, budget_s: float, left_s: float,
                       ends: int = 2, opening_s: float = 0.0) -> int:
    """The most readings that may be added at each of ``ends`` steps and still let the sweep and its proof
    end within ``budget_s``, and the sweep within its timeout (``left_s`` to it, with a fifth spare).
    ``spent_s`` of the budget is gone; each of the ``later`` steps and of the proof's :data:`PROOF_STEPS`
    costs ``step_s`` — the slowest step so far without its hold: a step's cost varies with the source's
    and the stream's timing, and a budget is a limit, not an average; the proof's opening and this
    sweep's closing cost ``opening_s`` each — what this sweep took to open its stream; a reading costs
    ``reading_s`` at the slowest compass."""
    rest = (later + PROOF_STEPS) * step_s + 2.0 * opening_s
    spare = min(budget_s - spent_s - rest, 0.8 * left_s - later * step_s)
    return max(0, int(spare / (ends * max(reading_s, 1e-4))))
