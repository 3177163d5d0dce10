"""Good units pass (issue 28): how many good simulated units the station rejects, and why.

Good units — distortions, noise and sensor rates inside what the station accepts, tumbled through all
orientations — go through the whole station (the sequencer with the shipped limits, the mounting
check included): ``--mock`` of them on the in-process mock (seeds, motions, 10–200 Hz sensors, noise
0.1–0.5 µT), ``--sim`` each (10–100 Hz) on the simulated PX4 and ArduPilot over real MAVLink.  Printed: PASS /
FAIL / ERROR counts, the cause of every non-PASS, and the drift test's statistic where it judged,
against χ²₃ and each test's own 10⁻³ threshold (3·F(3, dof)).  Goal: ≤ 1 false reject in 1,000 mock units, none on
the simulators.

    python benchmarks/false_reject.py [--mock 1000] [--sim 100] [--faults 0] [--jobs 1] [--seed 28]
                                       [--backends px4 ardupilot] [--px4-supply 0]

``--px4-supply N`` (issue 50): good units on the PX4 supply station (a true power cut through the
simulated SCPI supply) with a determined stop at the lowest coverage the station accepts (the mounting
check skipped, so nothing but the coverage and the fit's σ ends the tumble), the unit
resting after the power cycle where its tumble showed the field least: how many the post-power-cycle
proof fails (goal 0 of ≥ 1,000), with the firmware's calibrated field against the reference and the
fit's radial σ there.

Also printed: the limits behind every false reject (by rule), wrong orientations found on good
compasses (issue 26's "0 of 1,000"), and with ``--faults N`` every simulator fault run N times and
how often it was classified as ``magline.testing.faults`` says (FAIL: the unit is bad; ERROR: the
station could not judge it).
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

from magline.core.plugins import load_plugins
from magline.core.record import RunRecord
from magline.core.sequencer import Sequencer
from magline.core.station import load_station

REPO = Path(__file__).resolve().parents[1]
MOTIONS = ("hand_tumble", "full_sphere")


def _station(example: str, work: Path, product_changes: dict, acquisition: dict, station_id: str | None = None) -> Path:
    cfg = yaml.safe_load((REPO / "stations" / example).read_text(encoding="utf-8"))
    if station_id is not None:  # parallel runs: a station is one unit at a time
        cfg["station"]["id"] = station_id
    part = cfg["default_part"]
    for key, value in product_changes.items():
        if isinstance(value, dict):
            cfg["products"][part].setdefault(key, {}).update(value)
        else:
            cfg["products"][part][key] = value
    cfg["acquisition"].update(acquisition)
    cfg["results"] = {"sink": "sqlite", "path": str(work / "results.sqlite")}
    cfg["review"] = {"enabled": False}
    path = work / f"{example}-{time.monotonic_ns()}.yaml"
    path.write_text(yaml.safe_dump(cfg, sort_keys=False), encoding="utf-8")
    return path


def _good_mock_options(rng: np.random.Generator, work: Path, i: int) -> dict:
    """A unit inside the limits: offset ≤ 100 µT, axis ratio ≤ 1.2, noise 0.1–0.5 µT, a mounting within 1°."""
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    s = q @ np.diag(np.exp(rng.uniform(-0.08, 0.08, 3))) @ q.T
    return {"hard_iron_ut": [float(v) for v in rng.uniform(-55, 55, 3)], "soft_iron": s.round(6).tolist(),
            "noise_ut": float(rng.uniform(0.1, 0.5)), "motions": [str(rng.choice(MOTIONS))], "realtime": False,
            "misalignment_deg": [float(v) for v in rng.normal(0, 0.4, 3)], "seed": int(rng.integers(1 << 30)),
            "storage": str(work / f"mock-{i}.json"), "inclination_deg": 63.0}


def _failed_rules(record) -> list[str]:
    """The limits a unit failed, by catalogue rule (``mag2.`` and pair prefixes folded: one rule)."""
    from magline.core.measurements import Verdict, base_name, verdicts

    return sorted({base_name(m.name) for m in verdicts(record.measurements) if m.verdict is Verdict.FAIL})


def _why_not_judged(drift: dict, record) -> str:
    """Why a fit's drift test left no statistic: the readings could not tell a drift from the
    calibration (and how the acquisition ended), or the drift model's solve was refused."""
    from magline.core.fit.geometric import DRIFT_SEPARATION_MIN

    if drift.get("judged") is False and drift.get("separation", 0.0) < DRIFT_SEPARATION_MIN:
        ends = sorted({a.stopped for a in record.attempts}) or ["?"]
        return f"not separable (stopped: {'/'.join(str(e) for e in ends)})"
    return "the drift model's fit refused"


def _tally(name: str, records: list, started: float) -> None:
    verdicts = collections.Counter(str(r.verdict) for r in records)
    rules = collections.Counter(rule for r in records for rule in _failed_rules(r))
    compasses = sum(len((r.unit_info or {}).get("magnetometers") or [None]) for r in records)
    wrong = sum(1 for r in records for m in r.measurements
                if m.name.rsplit(".", 1)[-1] == "orientation" and str(getattr(m, "verdict", "")) == "fail")
    tests = [r.calibration["drift"] for r in records if r.calibration and r.calibration.get("drift")]
    judged = [d for d in tests if d.get("statistic") is not None]
    drift = np.array([d["statistic"] for d in judged])
    alarms = sum(d["statistic"] > d["threshold"] for d in judged)  # each against its own 3·F(3, dof) point
    print(f"{name}: {len(records)} good units in {time.monotonic() - started:.0f} s — "
          + ", ".join(f"{v.upper()} {n}" for v, n in sorted(verdicts.items())))
    for r in records:
        if str(r.verdict) != "pass":
            print(f"   {r.serial}: {str(r.verdict).upper()} {r.cause[:300]}")
            for a in r.attempts:  # enough to tell why: how each tumble ended, and the fit's drift decision
                print(f"      attempt {a.attempt}: stopped {a.stopped} after {a.tumble_s or 0.0:.1f} s, {a.samples} "
                      f"readings, coverage {a.coverage:.2f}, refused {a.refused}, predicted {a.predicted}")
            watched = ("warm_up_fraction", "rejected_fraction", "coverage", "direction_sigma_deg", "residual_rms_ut")
            fit_figures = [f"{m.name} {m.value:.3g}" for m in r.measurements
                           if isinstance(getattr(m, "value", None), float) and m.name.endswith(watched)]
            print(f"      {', '.join(fit_figures)}")
    # a drift test's false alarm no longer sets readings aside: the station measures again, at a tumble's cost
    again = sum(any((a.refused or "").startswith("warm-up: ") for a in r.attempts) for r in records)
    print(f"   false rejects by rule: {', '.join(f'{k} {v}' for k, v in rules.most_common()) or 'none'}; "
          f"wrong orientation found on {wrong} of {compasses} good compasses; "
          f"measured again for a warm-up: {again}")
    unjudged = collections.Counter(_why_not_judged(d, r) for r in records
                                   for d in [r.calibration.get("drift") if r.calibration else None]
                                   if d and d.get("statistic") is None)
    if unjudged:
        print(f"   drift tests without a statistic: {', '.join(f'{k} {v}' for k, v in unjudged.most_common())}")
    if drift.size:
        from scipy.stats import chi2

        print(f"   drift statistic, {drift.size} judged of {len(tests)} tests: median {np.median(drift):.2f} "
              f"(χ²₃ median {chi2.median(3):.2f}), p99 {np.percentile(drift, 99):.1f} (χ²₃ {chi2.ppf(0.99, 3):.1f}), "
              f"above its 10⁻³ threshold: {alarms}")


def mock_units(count: int, rng: np.random.Generator) -> None:
    started = time.monotonic()
    records = []
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for i in range(count):
            rate = float(rng.choice([10.0, 25.0, 50.0, 100.0, 200.0]))
            station = _station("demo.yaml", work, {"options": _good_mock_options(rng, work, i)},
                               {"rate_hz": rate, "retry_delay_s": 0.0})
            seq = Sequencer(load_station(station), load_plugins(), work, sleep=lambda s: None)
            try:
                records.append(seq.run_unit(f"GOOD-{i:05d}"))
            finally:
                seq.close()
    _tally("mock", records, started)


def _sim_unit(flavour: str, i: int, mags: int, seed: int, speed: float, rate_hz: float, motion: str) -> RunRecord:
    """One good unit on a simulator, in a folder of its own (units may go in parallel processes)."""
    from magline.sim import create_sim

    example, scheme = {"px4": ("px4-sim.yaml", "udp"), "ardupilot": ("ardupilot-sim.yaml", "tcp")}[flavour]
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        with create_sim(flavour, f"{scheme}:127.0.0.1:0", workdir=work / "fc", mag_count=mags, seed=seed,
                        boot_time_s=0.3, speed=speed, mag_rate_hz=rate_hz, motions=(motion,)) as sim:
            host, port = sim.address.split(":")[1:]
            url = f"udpout://{host}:{port}" if flavour == "px4" else f"tcp:{host}:{port}"
            station = _station(example, work, {"connection": url, "options": {"connect_timeout_s": 5.0}},
                               {"samples": 300, "rate_hz": 200.0, "timeout_s": 60.0, "retry_delay_s": 0.0},
                               station_id=f"good-{flavour}-{i}")
            seq = Sequencer(load_station(station), load_plugins(), work, sleep=lambda s: None)
            try:
                return seq.run_unit(f"{flavour.upper()}-{i:04d}")
            finally:
                seq.close()


def sim_units(flavour: str, count: int, rng: np.random.Generator, jobs: int = 1) -> None:
    """``count`` good units on the ``flavour`` simulator: 1–3 compasses, 10–100 Hz, tumble or gimbal at
    speed 0.5–2.  Each unit's draw is made here, in order, so ``jobs`` does not change which units run."""
    from concurrent.futures import ProcessPoolExecutor

    started = time.monotonic()
    draws = [(flavour, i, int(rng.integers(1, 4)), int(rng.integers(1 << 30)), float(rng.uniform(0.5, 2.0)),
              float(rng.choice([10.0, 25.0, 50.0, 100.0])), str(rng.choice(["tumble", "gimbal"])))
             for i in range(count)]
    if jobs > 1:
        with ProcessPoolExecutor(jobs) as pool:
            records = list(pool.map(_sim_unit, *zip(*draws, strict=True)))
    else:
        records = [_sim_unit(*draw) for draw in draws]
    _tally(flavour, records, started)


def _supply_unit(i: int, seed: int, speed: float, rate_hz: float) -> tuple[RunRecord, float]:
    """One good unit on the PX4 supply station, determined at the station's lowest accepted coverage."""
    from magline.sim import create_sim
    from magline.sim.supply import SupplySim

    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        with create_sim("px4", "udp:127.0.0.1:0", workdir=work / "fc", seed=seed, boot_time_s=0.3, speed=speed,
                        mag_rate_hz=rate_hz) as sim, SupplySim("tcp:127.0.0.1:0", board=sim) as supply:
            host, port = sim.address.split(":")[1:]
            cfg = yaml.safe_load((REPO / "stations" / "px4-sim-supply.yaml").read_text(encoding="utf-8"))
            lowest = float(cfg["limits"]["coverage"]["ge"])
            power = {"method": "scpi-supply", "options": {**cfg["products"][cfg["default_part"]]["power"]["options"],
                                                          "resource": supply.visa_resource, "off_time_s": 0.3}}
            station = _station("px4-sim-supply.yaml", work,
                               {"connection": f"udpout://{host}:{port}", "options": {"connect_timeout_s": 5.0},
                                "power": power, "orientation": "skip"},  # nothing but coverage and σ end it
                               {"stop": "determined", "coverage_target": lowest, "timeout_s": 60.0,
                                "retry_delay_s": 0.0, "wait_for_drift_test": False},
                               station_id=f"supply-{i}")
            seq = Sequencer(load_station(station), load_plugins(), work, sleep=lambda s: None)
            try:
                return seq.run_unit(f"PX4S-{i:04d}"), lowest
            finally:
                seq.close()


def supply_units(count: int, rng: np.random.Generator, jobs: int = 1) -> None:
    """``count`` good units on the PX4 supply station (speed 0.5–2, 25–100 Hz compasses): the
    post-power-cycle proof's verdicts and figures."""
    from concurrent.futures import ProcessPoolExecutor

    started = time.monotonic()
    draws = [(i, int(rng.integers(1 << 30)), float(rng.uniform(0.5, 2.0)), float(rng.choice([25.0, 50.0, 100.0])))
             for i in range(count)]
    with ProcessPoolExecutor(jobs) if jobs > 1 else contextlib.nullcontext() as pool:
        mapper = pool.map if pool is not None else map
        runs = list(mapper(_supply_unit, *zip(*draws, strict=True)))
    records = [r for r, _ in runs]
    _tally("px4 supply, determined at the lowest accepted coverage", records, started)
    verify_fails = [r for r in records if any(p.name == "verify" and str(p.outcome) == "fail" for p in r.phases)]
    figures = [r.persistence.get("figures", {}) for r in records if r.persistence]
    off = np.array([f["calibrated_field_ut"] / 48.0 * 100.0 - 100.0 for f in figures if "calibrated_field_ut" in f])
    sigma = np.array([f["calibrated_field_sigma_ut"] for f in figures if "calibrated_field_sigma_ut" in f])
    applied = np.array([abs(f["applied_difference_ut"]) for f in figures if "applied_difference_ut" in f])
    coverage = [m.value for r in records for m in r.measurements if m.name == "coverage"]
    old_check = int((np.abs(off) > 3.0).sum())  # the check before issue 50: ±3 % of the reference, nothing else
    print(f"   post-power-cycle proof: {len(verify_fails)} of {len(records)} FAIL at verify (goal 0); calibrated field "
          f"at rest {off.min():+.2f} … {off.max():+.2f} % of the reference — the old ±3 % check would FAIL "
          f"{old_check} of {len(off)}; fit radial σ there "
          f"median {np.median(sigma):.2f} µT, max {sigma.max():.2f} µT; |firmware − magline's calibration| median "
          f"{np.median(applied):.3f} µT, max {applied.max():.3f} µT; coverage at the stop {min(coverage):.3f} … "
          f"{max(coverage):.3f} (median {np.median(coverage):.3f}, lowest accepted {runs[0][1]:g})")
    for r in verify_fails:
        print(f"   {r.serial}: {r.cause[:200]}")


def _fault_run(name: str, i: int, seed: int) -> tuple[str, bool, str | None]:
    """One run of the fault table's row ``name`` on its simulator (``ARDUPILOT_FAULTS`` on the simulated
    ArduPilot, ``PX4_FAULTS`` on the simulated PX4, through the simulated supply where the row says), in
    a folder of its own (runs may go in parallel processes): (outcome, or "missed"; the cause's words
    found; the line to print when it was not classified as the table says, else None)."""
    from magline.sim import SimFaults, create_sim
    from magline.sim.supply import SupplySim
    from magline.testing.faults import ARDUPILOT_FAULTS, PX4_FAULTS

    px4 = any(c.name == name for c in PX4_FAULTS)
    case = next(c for c in (*ARDUPILOT_FAULTS, *PX4_FAULTS) if c.name == name)
    with tempfile.TemporaryDirectory() as tmp, contextlib.ExitStack() as stack:
        work = Path(tmp)
        listen = "udp:127.0.0.1:0" if px4 else "tcp:127.0.0.1:0"
        sim = stack.enter_context(create_sim("px4" if px4 else "ardupilot", listen,
                                             workdir=work / "fc", mag_count=case.mags, mag_rate_hz=100.0, seed=seed,
                                             boot_time_s=0.3, speed=5.0, faults=SimFaults.parse(list(case.faults))))
        options = {"connect_timeout_s": 5.0, "boot_timeout_s": 10.0 if case.passing_boot or px4 else 3.0}
        changes: dict = {"options": options}
        if px4:
            host, port = sim.address.split(":")[1:]
            changes["connection"] = f"udpout://{host}:{port}"
            if case.supply:
                supply = stack.enter_context(SupplySim("tcp:127.0.0.1:0", board=sim))
                changes["power"] = {"method": "scpi-supply", "options": {"resource": supply.visa_resource,
                                                                         "off_time_s": 0.3, "settle_s": 0.1}}
        else:
            changes["connection"] = sim.address
            options["prearm_wait_s"] = 0.3
        station = _station("px4-sim.yaml" if px4 else "ardupilot-sim.yaml", work, changes,
                           {"samples": 400, "rate_hz": 200.0, "timeout_s": 30.0, "retry_delay_s": 0.0,
                            **case.acquisition},
                           station_id=f"faults-{case.name}-{i}")
        seq = Sequencer(load_station(station), load_plugins(), work, sleep=lambda s: None)
        try:
            record = seq.run_unit(f"F-{case.name}-{i}")
        finally:
            seq.close()
    missed = case.missed(record)  # a PASS must also have left what the fault must leave
    wrong = str(record.verdict) != case.outcome or missed
    line = f"   {record.serial}: {str(record.verdict).upper()} {missed or record.cause[:200]}" if wrong else None
    return (str(record.verdict) if missed is None else "missed"), case.words in record.cause, line


def fault_units(count: int, rng: np.random.Generator, names: list[str] | None = None, jobs: int = 1) -> None:
    """The other side: every simulator fault of ``magline.testing.faults`` run ``count`` times across
    seeds on its simulator (ArduPilot's rows, then PX4's); printed: how often it was classified as the
    table says.
    ``jobs`` > 1 runs that many units at once in separate processes (the depth the goal asks,
    about 1,000 runs per row, is a night on a many-core machine)."""
    from concurrent.futures import ProcessPoolExecutor

    from magline.testing.faults import ARDUPILOT_FAULTS, PX4_FAULTS

    print(f"faults ({count} runs each, simulated ArduPilot then PX4, {jobs} at once): expected → PASS / FAIL / "
          "ERROR, cause words found")
    table = (*ARDUPILOT_FAULTS, *PX4_FAULTS)
    chosen = table if names is None else [c for c in table if c.name in names]
    seeds = {case.name: [int(rng.integers(1 << 30)) for _ in range(count)] for case in chosen}
    with ProcessPoolExecutor(jobs) if jobs > 1 else contextlib.nullcontext() as pool:
        # every row's runs queued at once: a row's slowest runs no longer leave the other workers idle
        queued = {case.name: (pool.map(_fault_run, [case.name] * count, range(count), seeds[case.name])
                              if pool is not None else None) for case in chosen}
        started = time.monotonic()
        for case in chosen:
            got, worded = collections.Counter(), 0
            runs = queued[case.name] or map(_fault_run, [case.name] * count, range(count), seeds[case.name])
            for outcome, found, line in runs:
                got[outcome] += 1
                worded += found
                if line:
                    print(line)
            right, missed = got[case.outcome], f" / missed {got['missed']}" if got["missed"] else ""
            print(f"   {case.name:<19} {case.outcome.upper():<5} → PASS {got['pass']} / FAIL {got['fail']} / ERROR "
                  f"{got['error']}{missed}: {right} of {count} right ({100.0 * right / count:.1f} %), words {worded} "
                  f"(done {time.monotonic() - started:.0f} s in)", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mock", type=int, default=1000)
    parser.add_argument("--sim", type=int, default=100)
    parser.add_argument("--faults", type=int, default=0, help="runs of each simulator fault (0: none)")
    parser.add_argument("--fault-names", nargs="+", default=None, help="only these rows of the fault table")
    parser.add_argument("--jobs", type=int, default=1,
                        help="simulated units (good ones and fault runs) at once, in separate processes")
    parser.add_argument("--seed", type=int, default=28)
    parser.add_argument("--backends", nargs="+", choices=["px4", "ardupilot"], default=["px4", "ardupilot"],
                        help="the simulators --sim runs on")
    parser.add_argument("--px4-supply", type=int, default=0,
                        help="good units on the PX4 supply station, determined at the lowest accepted coverage")
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    if args.mock:
        mock_units(args.mock, rng)
    for flavour in args.backends:
        if args.sim:
            sim_units(flavour, args.sim, rng, args.jobs)
    if args.px4_supply:
        supply_units(args.px4_supply, rng, args.jobs)
    if args.faults:
        fault_units(args.faults, rng, args.fault_names, args.jobs)
    sys.stdout.flush()


if __name__ == "__main__":
    main()
