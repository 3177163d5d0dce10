"""Is a tumble stopped early honest?  (issue 27: figures printed, never asserted)

Synthetic units (random hard and soft iron within the limits, 0.3 µT noise, the fit benchmark's
field) tumbled by the project's motions, read as the acquire phase reads them: the running fit is
judged at the same checkpoints (``min_samples``, then every 2.5 % more readings) with the same rule
(coverage at the target, predicted σ within 0.7 × the shipped limits of 0.5° and 0.5 µT).

Printed, for the early stop against the fixed 600-reading acquisition:
* where the tumbles stopped (readings);
* honesty of the predicted σ: the share of units whose true direction error, over the readings
  seen, exceeds 3 × the predicted heading σ (goal ≤ 0.3 %);
* the p95 over units of the largest heading error over level-to-30°-tilt attitudes (the fit
  benchmark's measure), and its change (goal ≤ 10 %).

Then ``--sim-units`` units as the simulators make them (``--sim-units 0``: skipped): the simulated
flight controllers' own motions (``tumble``, ``gimbal`` at speed 0.5–2), their compass rates (10 Hz
as ArduCopter reads it, 25–100 Hz as PX4's drivers do) and their wire (int16 milligauss truncated
toward zero, the backends' half-quantum added back), read at those rates in simulated time: the same
stop rule and honesty figure.  The MAVLink transport adds nothing to a reading past that wire
format; the whole-station runs over it are ``false_reject.py``'s.

With ``--warm-up UT …`` the simulated units also warm up (issue 28): their offset settles by UT µT
(time constant 3 s, a random direction) from their power-on, which is up to 8 s before the tumble
starts.  Printed per size: the share of drift tests that caught it (readings set aside or the drift
modelled), and how often the true error exceeds 3 × the predicted heading σ measured against the
offset at the stop (what the fit reports) and against the settled offset (what the unit holds later),
for the units caught and the units missed.

    python benchmarks/early_stop.py [--units 1000] [--sim-units 1000] [--seed 27] [--warm-up 2 4 10]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from magline.core.acquisition.tumble import CHECK_EVERY_FRACTION, CHECK_EVERY_MIN
from magline.core.fit import FitOptions, FitRefused, coverage_of, fit_calibration
from magline.core.fit.running import StopRule
from magline.sim.truth import motion_directions, random_truth

sys.path.insert(0, str(Path(__file__).parent))
from fit_benchmark import FIELD, E, heading_max

MOTIONS = ("hand_tumble", "full_sphere")
SAMPLES, MIN_SAMPLES, BINS, TARGET = 600, 100, 40, 0.6
LIMITS = {"": {"direction_sigma_deg": 0.5, "hard_iron_sigma_ut": 0.5}}  # the shipped station files'


def rule(margin: float, detectable_ut: float | None = None) -> StopRule:
    """The shipped stop rule; with ``detectable_ut`` also a station limit on ``drift_detectable_ut``."""
    limits = LIMITS if detectable_ut is None else {"": {**LIMITS[""], "drift_detectable_ut": detectable_ut}}
    return StopRule(min_samples=MIN_SAMPLES, coverage_target=TARGET, margin=margin, limits=limits, coverage={"": 0.5})
OPTIONS = FitOptions(model="full", field_ut=FIELD, coverage_bins=BINS)


def fit(m: np.ndarray, t_ms: np.ndarray):
    try:
        return fit_calibration(m, OPTIONS, t_ms=t_ms)
    except FitRefused:
        return None


def stop_point(m: np.ndarray, t_ms: np.ndarray, margin: float, detectable_ut: float | None = None):
    """The first checkpoint the acquire phase would stop at, and its fit (600 and theirs if none)."""
    judge = rule(margin, detectable_ut).judge
    n = MIN_SAMPLES
    while n < SAMPLES:
        if coverage_of(m[:n], BINS) >= TARGET:
            found = fit(m[:n], t_ms[:n])
            if found is not None and judge({"": found}) is not None:
                return n, found
        n += max(CHECK_EVERY_MIN, int(n * CHECK_EVERY_FRACTION))
    return SAMPLES, fit(m, t_ms)


def seen_error_deg(found, truth, directions: np.ndarray) -> float:
    """Largest true direction error over the orientations seen (noise-free readings calibrated)."""
    raw = np.linalg.solve(truth.soft_iron, (directions * FIELD).T).T + truth.hard_iron_ut
    cal = (raw - found.hard_iron_ut) @ found.soft_iron.T
    cos = np.sum(cal * directions, axis=1) / np.linalg.norm(cal, axis=1)
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))).max())


def simulator_unit(rng: np.random.Generator):
    """One unit as a simulator streams it: (truth, directions, readings µT, times ms)."""
    from magline.core.links.readings import untruncate_mg
    from magline.sim.truth.imu import simulator_fields

    truth = random_truth(rng)
    motion, speed = str(rng.choice(["tumble", "gimbal"])), float(rng.uniform(0.5, 2.0))
    rate = float(rng.choice([10.0, 25.0, 50.0, 100.0]))
    t = np.arange(SAMPLES) / rate + rng.uniform(0.0, 8.0)
    field_ned = E / np.linalg.norm(E) * FIELD
    body = simulator_fields(motion, t, speed, field_ned)
    wire_mg = np.trunc(truth.read(body, rng) * 10.0)  # the firmware's C conversion to int16 mG
    return truth, body / FIELD, untruncate_mg(wire_mg) / 10.0, t * 1000.0


WARM_UP_TAU_S = 3.0  # the simulators' fault table row: ``mag_warmup=10:3``


def warmed_unit(rng: np.random.Generator, size_ut: float):
    """A simulated unit whose offset settles by ``size_ut`` from its power-on at t = 0: (unit as
    :func:`simulator_unit` gives it, the offset still to settle at each reading µT)."""
    truth, directions, m, t_ms = simulator_unit(rng)
    way = rng.normal(size=3)
    left = np.outer(np.exp(-t_ms / 1000.0 / WARM_UP_TAU_S), way / np.linalg.norm(way) * size_ut)
    return (truth, directions, m + left, t_ms), left


def warm_up_bend(units: list, margin: float, detectable_ut: float | None = None) -> dict[str, list]:
    """Per kind (``caught`` / ``missed``): [units, true error > 3σ against the offset at the stop,
    > 3σ against the settled offset]; ``stops``: the readings each unit stopped at."""
    import dataclasses

    out: dict[str, list] = {"caught": [0, 0, 0], "missed": [0, 0, 0], "stops": []}
    for (truth, directions, m, t_ms), left in units:
        n, early = stop_point(m, t_ms, margin, detectable_ut)
        out["stops"].append(n)
        if early is None or not early.drift:
            continue
        kind = "caught" if early.drift.get("modelled") or early.drift.get("warm_up_excluded") else "missed"
        at_stop = dataclasses.replace(truth, hard_iron_ut=truth.hard_iron_ut + left[n - 1])
        limit = 3.0 * early.direction_sigma_deg
        out[kind][0] += 1
        out[kind][1] += seen_error_deg(early, at_stop, directions[:n]) > limit
        out[kind][2] += seen_error_deg(early, truth, directions[:n]) > limit
    return out


def honesty(units: list, margin: float) -> tuple[list[int], int, list[float], int]:
    """Per unit stopped early: where it stopped, whether its true error exceeded 3σ, its heading error."""
    stops, exceed, heading, refused = [], 0, [], 0
    for truth, directions, m, t_ms in units:
        n, early = stop_point(m, t_ms, margin)
        if early is None:
            refused += 1
            continue
        stops.append(n)
        exceed += seen_error_deg(early, truth, directions[:n]) > 3.0 * early.direction_sigma_deg
        heading.append(heading_max(early.hard_iron_ut, early.soft_iron, truth))
    return stops, exceed, heading, refused


def synthetic(args, rng: np.random.Generator) -> None:
    """The synthetic units' section: every margin against the fixed 600 readings."""
    units = []
    for unit in range(args.units):
        truth = random_truth(rng)
        directions = motion_directions(MOTIONS[unit % len(MOTIONS)], SAMPLES, rng, E / np.linalg.norm(E))
        units.append((truth, directions, truth.read(directions * FIELD, rng), np.arange(SAMPLES) * 20.0))
    fixed = [fit(m, t) for _, _, m, t in units]
    heading_fixed = [heading_max(f.hard_iron_ut, f.soft_iron, u[0]) for f, u in zip(fixed, units, strict=True)
                     if f is not None]
    p95_fixed = np.percentile(heading_fixed, 95)
    print(f"{args.units} synthetic units ({', '.join(MOTIONS)} alternating), {fixed.count(None)} refused by a fit "
          f"at 600 readings; fixed 600: p95 of the largest heading error {p95_fixed:.3f}°")
    print("goals: true error > 3σ in ≤ 0.30 % of units; p95 heading error at most +10 % against fixed 600")
    for margin in args.margins:
        stops, exceed, heading, refused = honesty(units, margin)
        p95 = np.percentile(heading, 95)
        print(f"sigma_margin {margin:<5g} stop at median {np.median(stops):.0f} readings (p95 "
              f"{np.percentile(stops, 95):.0f}); true error > 3σ: {exceed} of {len(stops)} "
              f"({exceed / len(stops):.2%}); "
              f"p95 heading {p95:.3f}° ({p95 / p95_fixed - 1:+.0%}){f'; {refused} refused' if refused else ''}",
              flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--units", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=27)
    parser.add_argument("--sim-units", type=int, default=1000, help="units as the simulators stream them")
    parser.add_argument("--margins", type=float, nargs="+", default=[0.7, 0.35, 0.2, 0.12],
                        help="sigma_margin values to compare (0.7: the default)")
    parser.add_argument("--warm-up", type=float, nargs="*", default=[],
                        help="µT: simulated units that also warm up by this much (0.7 margin)")
    parser.add_argument("--detectable-limits", type=float, nargs="*", default=[],
                        help="µT: with --warm-up, also stop with these limits on drift_detectable_ut")
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    if args.units:  # --units 0: the simulated units alone
        synthetic(args, rng)
    if args.sim_units:
        sims = [simulator_unit(rng) for _ in range(args.sim_units)]
        stops, exceed, heading, refused = honesty(sims, 0.7)
        fixed_sim = [heading_max(f.hard_iron_ut, f.soft_iron, truth) for truth, _, m, t in sims
                     if (f := fit(m, t)) is not None]
        print(f"{args.sim_units} units as the simulators stream them (tumble/gimbal, speed 0.5–2, 10–100 Hz, int16 "
              f"mG): sigma_margin 0.7 stops at median {np.median(stops):.0f} readings; true error > 3σ: {exceed} of "
              f"{len(stops)} ({exceed / max(len(stops), 1):.2%}); p95 heading {np.percentile(heading, 95):.3f}° "
              f"(fixed 600: {np.percentile(fixed_sim, 95):.3f}°)"
              f"{f'; {refused} refused' if refused else ''}", flush=True)

    for size in args.warm_up:
        units = [warmed_unit(rng, size) for _ in range(args.sim_units or 1000)]
        for limit in (None, *args.detectable_limits):
            bend = warm_up_bend(units, 0.7, limit)
            caught, missed = bend["caught"], bend["missed"]
            judged = caught[0] + missed[0]
            rule_words = "shipped rule" if limit is None else f"drift_detectable_ut ≤ {limit:g} µT"
            print(f"warm-up {size:g} µT (τ {WARM_UP_TAU_S:g} s), {rule_words}: stop at median "
                  f"{np.median(bend['stops']):.0f} readings (p95 {np.percentile(bend['stops'], 95):.0f}); caught in "
                  f"{caught[0]} of {judged} units; true error > 3σ against the offset at the stop / settled: "
                  f"caught {caught[1]} / {caught[2]}, missed {missed[1]} / {missed[2]} of {missed[0]}", flush=True)


if __name__ == "__main__":
    main()
