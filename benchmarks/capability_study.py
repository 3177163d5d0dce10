"""The capability study's statistics against known truth (issue 45): printed, never asserted.

    python benchmarks/capability_study.py [--series 1000] [--seed 45]

1. Run rules on stable data: ``--series`` simulated stable processes of 30 units each (normal, no
   cause), charted as ``magline spc`` charts them — limits frozen from a known process (Phase II) and
   provisional limits from the same 30 units (Phase I) — signals per chart and the share of charts
   with any signal, per rule.  Expected: the rules' own rate, from the Phase II charts of 100× as many
   series (limits known exactly).
2. Interval coverage: how often the 95 % interval of Cpk / Ppk holds the true index, for normal
   characteristics (n = 30, 50, 100) and for a log-normal one (Box-Cox chosen), over ``--series``
   samples each; and the percentile method's Ppk (ISO 22514-2, fitted Johnson SU; no interval) on a
   gamma-distributed characteristic: its median and spread against the true percentile Ppk.
3. The percentile method on a 10,000-unit window: its Ppk's spread and its cost when the shapes are
   fitted to 500 … 4,000 values spread evenly over the window (``FIT_VALUES``, shipped 2,000).
4. Families (issue 64): ``--families`` synthetic characteristics of 30 values each per family — normal,
   log-normal, gamma with a threshold, a quantised normal, a near-constant column — each against limits
   whose true Ppk (ISO percentiles of the generating distribution) is known: the share whose stated Ppk is
   within 10 % of the truth (and within 25 %), the share with no figure, the method chosen, and the count
   of degenerate shapes accepted (a fitted shape :func:`_refusal` would refuse; goal 0: none is ever used).

    python benchmarks/capability_study.py [--series 1000] [--seed 45] [--families 1000]
"""

from __future__ import annotations

import argparse
import math
import sys
import warnings
from pathlib import Path

import numpy as np
from scipy import stats

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from magline.core.quality.capability import capability
from magline.core.quality.charts import D2, frozen_chart, imr_chart
from magline.core.quality.rules import RULES

UNITS = 30


def rule_counts(series: int, rng: np.random.Generator, frozen: bool) -> tuple[dict[str, int], dict[str, int]]:
    """(signals per rule, charts with that rule's signal) over ``series`` stable charts of 30 units."""
    signals = dict.fromkeys(RULES, 0)
    charts = dict.fromkeys(RULES, 0)
    charts["any"] = signals["any"] = 0
    for _ in range(series):
        x = rng.normal(0.0, 1.0, UNITS)
        chart = frozen_chart("x", x, 0.0, 1.0, D2) if frozen else imr_chart("x", x, UNITS)
        seen = {s.rule for s in chart.signals}
        for s in chart.signals:
            signals[s.rule] += 1
            signals["any"] += 1
        for rule in seen:
            charts[rule] += 1
        charts["any"] += bool(seen)
    return signals, charts


def part_one(series: int, rng: np.random.Generator) -> None:
    print(f"1. run rules on {series} stable series of {UNITS} units (normal, no cause)")
    expected_signals, expected_charts = rule_counts(series * 100, rng, frozen=True)
    frozen_signals, frozen_charts = rule_counts(series, rng, frozen=True)
    provisional_signals, provisional_charts = rule_counts(series, rng, frozen=False)
    print(f"   {'rule':<24} {'expected/chart':>15} {'Phase II/chart':>15} {'Phase I/chart':>14} "
          f"{'charts: expected':>17} {'Phase II':>9} {'Phase I':>8}")
    for rule in [*RULES, "any"]:
        e = expected_signals[rule] / (series * 100)
        print(f"   {rule:<24} {e:15.3f} {frozen_signals[rule] / series:15.3f} "
              f"{provisional_signals[rule] / series:14.3f} {expected_charts[rule] / (series * 100):17.1%} "
              f"{frozen_charts[rule] / series:9.1%} {provisional_charts[rule] / series:8.1%}")


def coverage(samples: int, rng: np.random.Generator, draw, truth: float, low: float | None, high: float | None,
             method: str) -> tuple[float, float, float, str]:
    """(Cpk coverage, Ppk coverage — both among the draws ``method`` judged, the one whose truth ``truth``
    is —, median Ppk of those, the methods chosen over all draws) over ``samples`` draws."""
    cpk_in = ppk_in = judged = 0
    ppks, methods = [], {}
    for _ in range(samples):
        x = draw(rng)
        cap = capability(x, low, high, float(np.abs(np.diff(x)).mean() / D2) if x.size > 1 else 0.0)
        methods[cap.method] = methods.get(cap.method, 0) + 1
        if cap.ppk is None or cap.method != method:
            continue
        judged += 1
        ppks.append(cap.ppk.value)
        if cap.ppk.low is not None and cap.ppk.low <= truth <= cap.ppk.high:
            ppk_in += 1
        if cap.cpk is not None and cap.cpk.low is not None and cap.cpk.low <= truth <= cap.cpk.high:
            cpk_in += 1
    chosen = ", ".join(f"{k} {v / samples:.0%}" for k, v in sorted(methods.items()))
    return cpk_in / max(judged, 1), ppk_in / max(judged, 1), float(np.median(ppks)) if ppks else math.nan, chosen


def part_two(samples: int, rng: np.random.Generator) -> None:
    print(f"\n2. capability against known truth, {samples} samples per row (95 % intervals; coverage and median "
          "among the draws the row's method judged)")
    print(f"   {'characteristic':<34} {'n':>4} {'true':>6} {'median Ppk':>11} {'Cpk in CI':>10} {'Ppk in CI':>10}  "
          "method chosen")
    for n in (30, 50, 100):  # N(10, 1) against [4, 17]: Ppk = min(7, 6) / 3 = 2.0
        row = coverage(samples, rng, lambda r, n=n: r.normal(10.0, 1.0, n), 2.0, 4.0, 17.0, "normal")
        print(f"   {'normal N(10, 1), limits [4, 17]':<34} {n:4d} {2.0:6.2f} {row[2]:11.3f} {row[0]:10.1%} "
              f"{row[1]:10.1%}  {row[3]}")
    for n in (50, 100):  # ln x ~ N(0, 0.5) against USL e^1.5: on the log scale Ppk = 1.5 / 1.5 = 1.0
        row = coverage(samples, rng, lambda r, n=n: r.lognormal(0.0, 0.5, n), 1.0, None, float(np.exp(1.5)),
                       "box-cox")
        print(f"   {'log-normal (σ_ln 0.5), USL e^1.5':<34} {n:4d} {1.0:6.2f} {row[2]:11.3f} {row[0]:10.1%} "
              f"{row[1]:10.1%}  {row[3]}")
    # skewed and reaching below 0 (Box-Cox cannot take it): gamma(2, 1) − 1 against USL 11, whose ISO
    # percentile Ppk is (USL − X50) / (X99.865 − X50) of the true distribution
    gamma = stats.gamma(2.0, loc=-1.0, scale=1.0)
    x50, x99 = gamma.ppf([0.5, 0.99865])
    truth = (11.0 - x50) / (x99 - x50)
    for n in (50, 100, 200):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            row = coverage(samples // 4, rng, lambda r, n=n: gamma.rvs(size=n, random_state=r), truth, None, 11.0,
                           "percentile")
        print(f"   {'gamma(2, 1) − 1, USL 11':<34} {n:4d} {truth:6.2f} {row[2]:11.3f} {'—':>10} {'—':>10}  {row[3]}")


def part_three(samples: int, rng: np.random.Generator) -> None:
    """The percentile method on a large window fits its shapes to a subsample spread evenly over it
    (``FIT_VALUES``): what the subsample's size costs the Ppk's spread, and the time, at 500 … 4,000."""
    import time

    from magline.core.quality import capability as method

    gamma = stats.gamma(3.0, loc=10.0, scale=0.5)
    x50, x99 = gamma.ppf([0.5, 0.99865])
    truth = (18.0 - x50) / (x99 - x50)
    shipped = method.FIT_VALUES
    print(f"\n3. percentile Ppk of a 10,000-unit window (gamma(3) × 0.5 + 10, USL 18, true Ppk {truth:.3f}), "
          f"{samples} windows, the shapes fitted to a subsample of the window (shipped: {shipped})")
    print(f"   {'fitted values':>13} {'median Ppk':>11} {'SD':>7} {'SD / truth':>11} {'s per characteristic':>21}")
    windows = [gamma.rvs(size=10_000, random_state=rng) for _ in range(samples)]
    try:
        for size in (500, 1000, 2000, 4000):
            method.FIT_VALUES = size
            found, seconds = [], []
            for x in windows:
                t = time.perf_counter()
                chosen = method.best_shape(x)
                seconds.append(time.perf_counter() - t)
                if chosen is not None:
                    _, median, upper = chosen[1].ppf([0.00135, 0.5, 0.99865])
                    found.append((18.0 - median) / (upper - median))
            v = np.array(found)
            print(f"   {size:13d} {np.median(v):11.3f} {v.std():7.3f} {v.std() / truth:11.1%} "
                  f"{np.median(seconds):21.3f}")
    finally:
        method.FIT_VALUES = shipped


FAMILY_N = 30


def _families() -> dict[str, tuple[object, float | None, float | None, float]]:
    """name → (generating distribution, LSL, USL, quantisation step or 0)."""
    return {
        "normal": (stats.norm(10.0, 1.0), 5.0, 15.0, 0.0),
        "log-normal": (stats.lognorm(0.5, scale=1.0), None, float(np.exp(1.5)), 0.0),
        "gamma with a threshold": (stats.gamma(2.0, loc=1.0, scale=0.3), None, 4.0, 0.0),
        "quantised normal": (stats.norm(0.95, 0.01), 0.9, None, 0.01),
        "near-constant": (stats.norm(0.30, 0.01), None, 1.0, 0.0),
    }


def true_ppk(dist: object, low: float | None, high: float | None) -> float:
    lo, mid, hi = dist.ppf([0.00135, 0.5, 0.99865])  # type: ignore[attr-defined]
    sides = ([(high - mid) / (hi - mid)] if high is not None else []) + ([(mid - low) / (mid - lo)]
                                                                         if low is not None else [])
    return min(sides)


def part_four(count: int, rng: np.random.Generator) -> None:
    from magline.core.quality.capability import shape_fits

    print(f"\n4. families, {count} characteristics of {FAMILY_N} values each: stated Ppk against the true one")
    print(f"   {'family':<24} {'true Ppk':>8} {'within 10 %':>11} {'within 25 %':>11} {'no figure':>9} "
          f"{'degenerate used':>15}  methods")
    for name, (dist, low, high, step) in _families().items():
        truth = true_ppk(dist, low, high)
        close = near = none = degenerate = 0
        methods: dict[str, int] = {}
        for _ in range(count):
            x = dist.rvs(size=FAMILY_N, random_state=rng)  # type: ignore[attr-defined]
            if step:
                x = np.round(x / step) * step
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                found = capability(x, low, high, float(np.abs(np.diff(x)).mean() / D2), min_units=FAMILY_N)
            methods[found.method] = methods.get(found.method, 0) + 1
            if found.ppk is None:
                none += 1
                continue
            error = abs(found.ppk.value / truth - 1)
            close += error <= 0.10
            near += error <= 0.25
            if found.method == "percentile" and found.shape is not None:
                fitted = [f for f in shape_fits(x) if f.dist is found.shape]
                degenerate += bool(fitted and fitted[0].refused)
        print(f"   {name:<24} {truth:8.2f} {close / count:11.1%} {near / count:11.1%} {none / count:9.1%} "
              f"{degenerate:15d}  " + ", ".join(f"{m} {n}" for m, n in sorted(methods.items())))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--series", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=45)
    parser.add_argument("--families", type=int, default=1000, help="characteristics per family in part 4")
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    if args.series:
        part_one(args.series, rng)
        part_two(args.series, rng)
        part_three(max(20, args.series // 25), rng)
    if args.families:
        part_four(args.families, rng)
    return 0


if __name__ == "__main__":
    sys.exit(main())
