"""Issue 47's figures: how close the INAV backend's written calibration is to the simulated compass's truth,
in INAV's own terms, and what a unit costs against the MAVLink backends.

1. Accuracy (``--units`` boards, each its own seeded compass, once without cross terms and once with the
   simulator's own): the written ``magzero_*`` against the
   truth ``counts·h`` (goal ≤ 1 raw count) and each ``maggain_*`` against ``counts·B/S_ii`` (goal ≤ 0.1 %),
   over MSP on loopback, the compass sped up to 50 Hz and the tumble ×3 (the accuracy depends on the
   readings, not on how fast they come): at the shipped station (stop as soon as the calibration is
   determined) and at 2,400 readings, and what of the error is the conversion (rounding to INAV's
   integers) and what the fit's own statistical error.
2. Cycle time (``--cycles`` units per backend) at the shipped station files and the simulators' shipped
   defaults (boot 2 s; INAV's compass at its 10 Hz), INAV against PX4 and ArduPilot.

    python benchmarks/inav.py [--units 20] [--cycles 2] [--seed 47]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from pathlib import Path

import numpy as np
import yaml
from timed_unit import timed_unit

from magline.core.record import Outcome
from magline.plugin import INAV_TO_FRD
from magline.sim import create_sim
from magline.sim.inav import inav_compass
from magline.sim.magnetometers import SimMagnetometer

REPO = Path(__file__).resolve().parents[1]
EXAMPLES = {"inav": ("inav-sim.yaml", "tcp:127.0.0.1:0"), "px4": ("px4-sim.yaml", "udp:127.0.0.1:0"),
            "ardupilot": ("ardupilot-sim.yaml", "tcp:127.0.0.1:0")}
CONNECTION = {"inav": "{}", "px4": "udpout://{}", "ardupilot": "tcp:{}"}


def station(flavour: str, folder: Path, address: str, samples: int | None = None) -> Path:
    example, _ = EXAMPLES[flavour]
    cfg = yaml.safe_load((REPO / "stations" / example).read_text(encoding="utf-8"))
    if samples is not None:  # that many readings, not "as soon as determined" (the shipped station's stop rule)
        cfg["acquisition"] |= {"samples": samples, "stop": "samples", "timeout_s": samples / 10.0}
    part = cfg["default_part"]
    target = address if flavour == "inav" else CONNECTION[flavour].format(address.split(":", 1)[1])
    cfg["products"][part]["connection"] = target
    cfg["results"] = {"sink": "sqlite", "path": str(folder / "results.sqlite")}
    path = folder / "station.yaml"
    path.write_text(yaml.safe_dump(cfg, sort_keys=False), encoding="utf-8")
    return path



def compass(seed: int, cross: bool) -> SimMagnetometer:
    """The simulator's compass for ``seed``; without its small cross terms when ``cross`` is False (what
    INAV's per-axis gains can hold exactly)."""
    sensor = inav_compass(np.random.default_rng(seed))
    if not cross:
        sensor = SimMagnetometer(device_id=1, hard_iron_ut=sensor.hard_iron_ut,
                                 soft_iron=np.diag(np.diag(sensor.soft_iron)))
    return sensor


def accuracy(units: int, seed: int, cross: bool, samples: int | None) -> None:
    what = "the simulator's compasses (cross terms up to ±0.004)" if cross else "compasses without cross terms"
    readings = f"{samples} readings each" if samples else "the shipped station (stop: determined)"
    print(f"1. accuracy over MSP, {units} simulated INAV units, {what}, {readings} "
          "(goals: offset ≤ 1 raw count, gain ≤ 0.1 %)")
    taken = []
    offsets, gains, verdicts, rounding, z_scores, sigma_counts = [], [], [], [], [], []
    for n in range(units):
        with tempfile.TemporaryDirectory() as tmp:
            folder = Path(tmp)
            with create_sim("inav", "tcp:127.0.0.1:0", workdir=folder / "fc", seed=seed + n, boot_time_s=0.3,
                            speed=3.0, mag_rate_hz=50.0, magnetometers=[compass(seed + n, cross)]) as sim:
                record, _ = timed_unit(station("inav", folder, sim.address, samples), f"INAV-{n:04d}")
                stored = sim.read_storage()
                truth = sim.magnetometers[0]
                counts = sim.counts_per_ut
        verdicts.append(str(record.verdict))
        if record.verdict is not Outcome.PASS:
            print(f"   unit {n}: {record.verdict} ({record.cause})")
            continue
        taken.append(sum(a.samples for a in record.attempts if a.accepted))
        field = float(record.calibration["field_ut"])
        fitted = np.asarray(record.calibration["hard_iron_ut"], float)
        sigma = np.asarray(record.calibration["hard_iron_sigma_ut"], float)
        # magline's fit is in forward-right-down axes, INAV's magzero in its forward-left-up sensor axes
        in_inav = np.array(INAV_TO_FRD, float)
        rounding += [abs(stored[f"magzero_{a}"] - counts * h) for a, h in zip("xyz", in_inav @ fitted, strict=True)]
        z_scores += list(np.abs(fitted - truth.hard_iron_ut) / sigma)
        sigma_counts += list(sigma * counts)
        offsets += [abs(stored[f"magzero_{a}"] - counts * h)
                    for a, h in zip("xyz", in_inav @ truth.hard_iron_ut, strict=True)]
        gains += [abs(stored[f"maggain_{a}"] / (counts * field / s) - 1) * 100
                  for a, s in zip("xyz", np.diag(truth.soft_iron), strict=True)]
    if offsets:
        print(f"   passed {verdicts.count('pass')} of {units}, median {statistics.median(taken):.0f} readings; "
              "per axis over the passed units:")
        print(f"   offset error, raw counts: median {statistics.median(offsets):.2f}, p95 "
              f"{np.percentile(offsets, 95):.2f}, max {max(offsets):.2f} (1 count = {1 / counts:.3f} µT)")
        print(f"   gain error, %: median {statistics.median(gains):.3f}, p95 {np.percentile(gains, 95):.3f}, "
              f"max {max(gains):.3f}")
        print(f"   the conversion alone (written against the fit's own offset): max {max(rounding):.2f} counts; the "
              f"fit's own σ median {statistics.median(sigma_counts):.2f} counts, its offset within 3σ of the truth "
              f"on {sum(z < 3 for z in z_scores)} of {len(z_scores)} axes")


def cycle_times(cycles: int, seed: int) -> None:
    print(f"2. cycle time per unit, {cycles} per backend, shipped station files and simulator defaults")
    print(f"   {'backend':<10} {'median s':>9} {'units/h':>8}  phases (median s)")
    for flavour in ("inav", "px4", "ardupilot"):
        walls, phases = [], {}
        for n in range(cycles):
            with tempfile.TemporaryDirectory() as tmp:
                folder = Path(tmp)
                _, listen = EXAMPLES[flavour]
                with create_sim(flavour, listen, workdir=folder / "fc", seed=seed + n) as sim:
                    record, wall = timed_unit(station(flavour, folder, sim.address), f"{flavour}-{n}")
            if record.verdict is not Outcome.PASS:
                print(f"   {flavour} unit {n}: {record.verdict} ({record.cause})")
            walls.append(wall)
            for p in record.phases:
                phases.setdefault(p.name, []).append(p.duration_s)
        median = statistics.median(walls)
        parts = ", ".join(f"{k} {statistics.median(v):.1f}" for k, v in phases.items())
        print(f"   {flavour:<10} {median:>9.1f} {3600 / median:>8.0f}  {parts}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--units", type=int, default=20)
    parser.add_argument("--cycles", type=int, default=2)
    parser.add_argument("--seed", type=int, default=47)
    args = parser.parse_args(argv)
    for cross, samples, units in ((False, None, args.units), (True, None, args.units),
                                  (False, 2400, max(args.units // 2, 1))):
        accuracy(units, args.seed, cross, samples)
    cycle_times(args.cycles, args.seed)
    return 0


if __name__ == "__main__":
    sys.exit(main())
