"""When is a tumble called stalled?  (figures printed, never asserted)

A determined tumble that cannot reach its coverage target ends, and the operator is asked again
(``core/acquisition/tumble_stop.py``, ``Stall``).  Called too early, a good tumble's readings are thrown away;
called too late, an operator spinning the unit about its vertical is told only after many seconds.  This
benchmark drives the shipped rule with the shipped coverage tracker (40 bins, target 60 %, ``min_samples``
100), the magnetometer's readings and the accelerometer's in chunks of ten as the acquire phase feeds them, on:

* a spin about the vertical, one turn in 600 readings, with a 0°, 3°, 8° and 15° hand wobble (the classic
  mistake): it must stall within 300 readings;
* the simulators' tumble and gimbal at 50 Hz, begun at a random point of their sweep, at their own speed (a
  sweep in 400 readings) and slowed to a sweep in 3,000 readings; the two-axis gimbal; an operator's tumble
  face by face over 600 and, slowly, 3,000 readings: they must never stall;
* a turntable's unit, one turn per cradle tilt: it must never stall.

A gimbal or a turntable turns its unit about the vertical by design: the rule for a turn about the vertical is
left out for them, as the station leaves it out for any motion but a person's (``motion.type: operator``).

Printed per motion: how many were called stalled, at how many readings (median, most) and for the spins how
many only after 300 readings or never.

    python benchmarks/stall.py [--units 100] [--seed 27]
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy.spatial.transform import Rotation

from magline.core.acquisition.tumble_stop import Stall
from magline.core.fit.coverage import CoverageTracker
from magline.sim.magnetometers import attitude
from magline.sim.truth.attitudes import two_axis_attitude
from magline.sim.truth.motions import cradle_attitudes, hand_tour_attitudes, ring_attitudes

FIELD = np.array([20.0, 1.5, 42.0])  # µT, NED: 48 µT dipping 63°
INCLINATION_DEG = float(np.degrees(np.arctan2(FIELD[2], np.hypot(FIELD[0], FIELD[1]))))
UP_NED = np.array([0.0, 0.0, -9.80665])  # what an accelerometer at rest reads, in NED
BINS, TARGET, MIN_SAMPLES, CHUNK = 40, 0.6, 100, 10
HARD_IRON = np.array([30.0, -20.0, 10.0])
SOON = 300  # readings: the spin's half turn, 6 s at 50 Hz
RATE_HZ = 50.0
SWEEP_READINGS = 400  # the simulators' pole-to-pole sweep at speed 1: 8 s at 50 Hz


def stalled_at(attitudes: Rotation, rng: np.random.Generator, about_vertical: bool = True) -> int | None:
    """The reading at which the shipped rule calls the tumble stalled (None: it reached the target or
    never stalled)."""
    stall = Stall(MIN_SAMPLES, TARGET, about_vertical=about_vertical, field_ut=float(np.linalg.norm(FIELD)),
                  inclination_deg=INCLINATION_DEG)
    tracker = CoverageTracker(BINS)
    mags = attitudes.inv().apply(FIELD) + HARD_IRON + rng.normal(0.0, 0.3, (len(attitudes), 3))
    accel = attitudes.inv().apply(UP_NED) + rng.normal(0.0, 0.5, (len(attitudes), 3))  # a hand's jitter
    for start in range(0, len(mags), CHUNK):
        n = min(start + CHUNK, len(mags))
        coverage = tracker.add(mags[start:n])
        stall.see(mags[start:n], accel[start:n], n)
        if coverage >= TARGET:
            return None
        if stall.stalled(n, coverage):
            return n
    return None


def simulator(motion: str, rng: np.random.Generator, sweep_readings: int = SWEEP_READINGS) -> Rotation:
    """The simulators' own motion at 50 Hz, slowed so that one pole-to-pole sweep takes ``sweep_readings``
    readings, for four sweeps from anywhere in its cycle."""
    speed = SWEEP_READINGS / sweep_readings
    t = rng.uniform(0.0, 32.0 / speed) + np.arange(0, 4 * sweep_readings) / RATE_HZ
    return Rotation.concatenate([attitude(motion, s, speed, FIELD) for s in t])


def hand(readings: int, rng: np.random.Generator) -> Rotation:
    """An operator's tumble face by face over ``readings``, twice over (a slow one may need more)."""
    return Rotation.concatenate([hand_tour_attitudes(readings, rng), hand_tour_attitudes(readings, rng)])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--units", type=int, default=100)
    parser.add_argument("--seed", type=int, default=27)
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    z = np.array([0.0, 0.0, 1.0])

    def spin(wobble: float) -> Rotation:
        return Rotation.concatenate([ring_attitudes(600, rng, z, wobble) for _ in range(8)])

    motions = {
        "spin, no wobble": lambda: spin(0.0),
        "spin, 3° wobble": lambda: spin(3.0),
        "spin, 8° wobble": lambda: spin(8.0),
        "spin, 15° wobble": lambda: spin(15.0),
        "simulator tumble 50 Hz": lambda: simulator("tumble", rng),
        "slow simulator tumble": lambda: simulator("tumble", rng, 3000),
        "simulator gimbal 50 Hz": lambda: simulator("gimbal", rng),
        "slow simulator gimbal": lambda: simulator("gimbal", rng, 3000),
        "two-axis gimbal 50 Hz": lambda: two_axis_attitude(rng.uniform(0, 60) + np.arange(3000) / RATE_HZ),
        "hand tumble (600)": lambda: hand(600, rng),
        "slow hand tumble (3,000)": lambda: hand(3000, rng),
        "turntable": lambda: cradle_attitudes(4000, rng),
    }
    print(f"stall rule: gravity within {Stall.SPIN_CAP_DEG:g}° while the field swept {Stall.SPIN_SWEEP_DEG:g}° "
          f"about it, or no new direction (field nor gravity) over {Stall.WITHOUT_GROWTH:.2f} of the readings; at "
          f"least {2 * MIN_SAMPLES} readings; {BINS} bins, target {TARGET:.0%}; {args.units} tumbles each")
    for name, make in motions.items():
        by_hand = not any(word in name for word in ("gimbal", "turntable"))  # a fixture turns about the vertical
        at = [stalled_at(make(), rng, about_vertical=by_hand) for _ in range(args.units)]
        stalled = [n for n in at if n is not None]
        line = f"  {name:<26} stalled {len(stalled):4d} of {len(at)}"
        if stalled:
            line += f"  at readings p50 {np.median(stalled):.0f}, most {max(stalled)}"
        if name.startswith("spin"):
            late = sum(n is None or n > SOON for n in at)
            line += f"; later than {SOON} readings (or never) in {late}"
        print(line, flush=True)


if __name__ == "__main__":
    main()
