"""How the README's first command goes, unit after unit: the attempts each demo unit takes and its verdict.

The embedded demo station (``stations/demo.yaml``) in simulated time, one seed per unit: its simulated operator
spins the unit about its vertical first (coverage too low: one retry), then tumbles it.  Printed: how many
units took which attempts (each attempt by why it was refused), and the verdicts.  A unit measured again as a
warm-up is the drift test's false alarm (p = 10⁻³ by design: the demo's mock does not drift).

    python benchmarks/demo_attempts.py [--units 200] [--seed 10000]
"""

from __future__ import annotations

import argparse
import re
import sys
import tempfile
from collections import Counter
from pathlib import Path

import yaml

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from conftest import demo_config

from magline.core.plugins import load_plugins
from magline.core.sequencer import Sequencer
from magline.core.station import load_station
from magline.testing import deep_update


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--units", type=int, default=200)
    parser.add_argument("--seed", type=int, default=10_000)
    args = parser.parse_args()
    plugins = load_plugins()
    patterns: Counter[tuple[str, ...]] = Counter()
    verdicts: Counter[str] = Counter()
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.seed, args.seed + args.units):
            station = Path(tmp) / "demo.yaml"
            station.write_text(yaml.safe_dump(deep_update(demo_config(), {
                "products": {"MOCK-100": {"options": {"realtime": False, "seed": seed,
                                                      "storage": str(Path(tmp) / f"storage-{seed}.json")}}},
                "acquisition": {"retry_delay_s": 0.0}})), encoding="utf-8")
            sequencer = Sequencer(load_station(station), plugins, Path(tmp), sleep=lambda s: None)
            try:
                record = sequencer.run_unit(f"DEMO-{seed}")
            finally:
                sequencer.close()
            # each refused attempt by the start of its reason, its figures left out ("coverage 12% below …")
            patterns[tuple(re.sub(r"[\d.]+%?", "…", a.refused or "accepted")[:40] for a in record.attempts)] += 1
            verdicts[record.verdict.value] += 1
    print(f"{args.units} demo units (seeds {args.seed}–{args.seed + args.units - 1}), simulated time")
    for pattern, count in patterns.most_common():
        print(f"{count:6d}  {' → '.join(pattern)}")
    print("verdicts: " + ", ".join(f"{v} {n}" for v, n in verdicts.most_common()))


if __name__ == "__main__":
    main()
