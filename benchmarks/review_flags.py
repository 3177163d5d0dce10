"""How often the in-run process review flags good units, per measurement (its nominal rate at 3σ is
about 0.3 % per measurement).

A simulated line of one design: every unit the demo station's mock with an offset a few µT from the
design's (σ 3 µT per axis), soft iron within 1 %, a mounting within 0.3°, noise 0.3 µT, the operator's
hand tumble, a determined stop.  The first ``min_units`` units build the history; every later unit is
reviewed against the last ``window`` passing ones, as on a line.  Printed: verdicts, units reviewed,
and per measurement the flags and their signed distances in σ — marked where the station's default
``review.exclude`` leaves the measurement out.

    python benchmarks/review_flags.py [--units 230] [--seed 7] [--exclude attempts]

``--exclude`` replaces the station's list (``--exclude attempts``: the review as it was before the
uncertainties were excluded by default).
"""

from __future__ import annotations

import argparse
import collections
import tempfile
from pathlib import Path

import numpy as np
import yaml

from magline.core.plugins import load_plugins
from magline.core.sequencer import Sequencer
from magline.core.station import load_station
from magline.core.station.schema import NOT_PROCESS_FIGURES

REPO = Path(__file__).resolve().parent.parent
DESIGN_OFFSET_UT = np.array([20.0, -12.0, 35.0])


def unit_options(rng: np.random.Generator, work: Path, i: int) -> dict:
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    soft = q @ np.diag(np.exp(rng.normal(0, 0.01, 3))) @ q.T
    return {"hard_iron_ut": (DESIGN_OFFSET_UT + rng.normal(0, 3, 3)).tolist(), "soft_iron": soft.round(6).tolist(),
            "motions": ["hand_tumble"], "realtime": False, "noise_ut": 0.3,
            "misalignment_deg": rng.normal(0, 0.3, 3).tolist(), "seed": int(rng.integers(1 << 30)),
            "storage": str(work / f"mock-{i}.json")}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--units", type=int, default=230)
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--exclude", nargs="*", default=None, help="replaces the station's review.exclude")
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    verdicts, flags, distances, reviewed = collections.Counter(), collections.Counter(), {}, 0
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        cfg = yaml.safe_load((REPO / "stations" / "demo.yaml").read_text(encoding="utf-8"))
        cfg["results"] = {"sink": "sqlite", "path": str(work / "results.sqlite")}
        cfg["acquisition"]["retry_delay_s"] = 0.0
        if args.exclude is not None:
            cfg["review"] = {"exclude": args.exclude}
        for i in range(args.units):
            unit = yaml.safe_load(yaml.safe_dump(cfg))
            unit["products"]["MOCK-100"]["options"] |= unit_options(rng, work, i)
            path = work / f"station-{i}.yaml"
            path.write_text(yaml.safe_dump(unit, sort_keys=False), encoding="utf-8")
            seq = Sequencer(load_station(path), load_plugins(), work, sleep=lambda s: None)
            try:
                record = seq.run_unit(f"U{i:04d}")
            finally:
                seq.close()
            verdicts[str(record.verdict)] += 1
            reviewed += (record.review_note or "").startswith("compared with the last")
            for flag in record.review:
                flags[flag["name"]] += 1
                distances.setdefault(flag["name"], []).append(round(flag["z"], 1))
    print(f"{args.units} units: " + ", ".join(f"{v.upper()} {n}" for v, n in sorted(verdicts.items()))
          + f"; reviewed {reviewed}; flags {sum(flags.values())}")
    for name, count in flags.most_common():
        note = "  (not reviewed by default)" if name in NOT_PROCESS_FIGURES else ""
        print(f"   {name:<24} {count:>3} flags ({100.0 * count / max(reviewed, 1):.1f} % of units), "
              f"at {sorted(distances[name])} σ{note}")


if __name__ == "__main__":
    main()
