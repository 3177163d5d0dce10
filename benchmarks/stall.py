"""When is a tumble called stalled?  (issue 27: figures printed, never asserted)

A determined tumble whose coverage stops growing short of its target ends, and the operator is asked
again (``core/acquisition/tumble_stop.py``, ``Stall``).  Called too early, a good tumble's readings are thrown away;
called too late, an operator spinning the unit about one axis is told only after many seconds.  This
benchmark drives the shipped rule with the shipped coverage tracker (40 bins, target 60 %,
``min_samples`` 100), readings as the acquire phase feeds them, on:

* a spin about the vertical axis with a 3° and a 15° hand wobble (the classic mistake; the demo's
  mock makes the 15° one, a fresh turn every 600 readings): it must stall, soon;
* the simulators' tumble and gimbal at 50 Hz, begun at a random point of their sweep (a turn there
  and back: no new direction while it retraces), at their own speed (a sweep in 400 readings) and
  slowed to a sweep in 3,000 readings: they must not;
* an operator's hand tumble through well-spread waypoints, over 600 readings and, slowly, over 3,000:
  they must not.

Printed per motion: how many were called stalled, and for the spins at how many readings (median,
most) and how many only after 1,000 readings or never (a spin whose wobble finds a new direction now
and then creeps on: the few that do make a percentile unstable, so they are counted).

    python benchmarks/stall.py [--units 100] [--seed 27] [--without-growth 0.5]
"""

from __future__ import annotations

import argparse

import numpy as np

from magline.core.acquisition.tumble_stop import Stall
from magline.core.fit.coverage import CoverageTracker
from magline.sim.truth.imu import simulator_fields
from magline.sim.truth.motions import hand_tumble, single_axis

FIELD = np.array([20.0, 1.5, 42.0])  # µT, NED: 48 µT dipping 63°
BINS, TARGET, MIN_SAMPLES = 40, 0.6, 100
HARD_IRON = np.array([30.0, -20.0, 10.0])
LATE = 1000  # readings: 5 s at the demo's 200 Hz, 20 s at 50 Hz


def stalled_at(directions: np.ndarray, rng: np.random.Generator) -> int | None:
    """The reading at which the shipped rule calls the tumble stalled (None: it reached the target or
    never stalled)."""
    stall, tracker = Stall(MIN_SAMPLES, TARGET), CoverageTracker(BINS)
    readings = directions * np.linalg.norm(FIELD) + HARD_IRON + rng.normal(0.0, 0.3, directions.shape)
    for n, reading in enumerate(readings, start=1):
        coverage = tracker.add(reading[None])
        if coverage >= TARGET:
            return None
        if stall.stalled(n, coverage):
            return n
    return None


SWEEP_READINGS = 400  # the simulators' pole-to-pole sweep at speed 1: 8 s at 50 Hz


def simulator(motion: str, rng: np.random.Generator, sweep_readings: int = SWEEP_READINGS) -> np.ndarray:
    """The simulators' own motion at 50 Hz, slowed so that one pole-to-pole sweep takes ``sweep_readings``
    readings, for four sweeps from anywhere in its cycle."""
    speed = SWEEP_READINGS / sweep_readings
    t = rng.uniform(0.0, 32.0 / speed) + np.arange(0, 4 * sweep_readings) / 50.0
    return simulator_fields(motion, t, speed, FIELD) / np.linalg.norm(FIELD)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--units", type=int, default=100)
    parser.add_argument("--seed", type=int, default=27)
    parser.add_argument("--without-growth", type=float, default=None,
                        help="the rule's share of readings without a new direction (default: the shipped one)")
    args = parser.parse_args()
    if args.without_growth is not None:
        Stall.WITHOUT_GROWTH = args.without_growth
    rng = np.random.default_rng(args.seed)
    down = FIELD / np.linalg.norm(FIELD)
    motions = {
        "spin, 3° wobble": lambda: np.vstack([single_axis(600, rng, down, 3.0) for _ in range(8)]),
        "spin, 15° wobble": lambda: np.vstack([single_axis(600, rng, down, 15.0) for _ in range(8)]),
        "simulator tumble 50 Hz": lambda: simulator("tumble", rng),
        "slow simulator tumble": lambda: simulator("tumble", rng, 3000),
        "simulator gimbal 50 Hz": lambda: simulator("gimbal", rng),
        "slow simulator gimbal": lambda: simulator("gimbal", rng, 3000),
        "hand tumble (600)": lambda: hand_tumble(600, rng, down),
        "slow hand tumble (3,000)": lambda: hand_tumble(3000, rng, down),
    }
    print(f"stall rule: no new direction over {Stall.WITHOUT_GROWTH:.2f} of the readings, at least "
          f"{MIN_SAMPLES}; {BINS} bins, target {TARGET:.0%}; {args.units} tumbles each")
    for name, make in motions.items():
        tumbles = [make() for _ in range(args.units)]
        at = [stalled_at(directions, rng) for directions in tumbles]
        stalled = [n for n in at if n is not None]
        line = f"  {name:<26} stalled {len(stalled):4d} of {len(at)}"
        if name.startswith("spin") and stalled:
            late = sum(n is None or n > LATE for n in at)  # most spins stall at once, a few creep on
            line += (f"  at readings p50 {np.median(stalled):.0f}, most {max(stalled)}; later than {LATE:,} "
                     f"readings (or never within {len(tumbles[0]):,}) in {late}")
        print(line, flush=True)


if __name__ == "__main__":
    main()
