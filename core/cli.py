"""``magline`` command line: run a station, check a station file, fit a CSV, list plugins, history.

Plugins add their own sub-commands through ``magline_add_commands`` (the mock plugin: ``sim``).

Exit codes of ``magline run``: 0 pass, 1 fail, 2 error (bad station file, no DUT, plugin error).
"""

from __future__ import annotations

import argparse
import json
import sys
from importlib.resources import as_file, files
from pathlib import Path

from pydantic import ValidationError

from magline.core import __version__
from magline.core.fit import FitOptions, FitRefused, fit_calibration
from magline.core.fit.affine import fit_affine
from magline.core.fit.samples_csv import SampleFileError, read_samples
from magline.core.plugins import PluginError, Plugins, load_plugins
from magline.core.record import Outcome
from magline.core.station import Station, StationError, load_station_text
from magline.core.station.loader import line_of, read_station_text

EXIT = {Outcome.PASS: 0, Outcome.FAIL: 1, Outcome.ERROR: 2, Outcome.SKIPPED: 2}
DEMO = "demo.yaml"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="magline", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"magline {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    run = sub.add_parser("run", help="calibrate units on a station (default: the embedded mock demo)")
    run.add_argument("station", nargs="?", help="station file (default: the embedded demo station)")
    run.add_argument("--serial", help="unit serial (else prompt, or generated for the demo)")
    run.add_argument("--part", help="part number (else the station's default)")
    run.add_argument("--operator", default="", help="operator name for the record")
    run.add_argument("--loop", action="store_true", help="keep prompting for the next serial")

    check = sub.add_parser("check", help="validate a station file")
    check.add_argument("station")

    fit = sub.add_parser("fit", help="fit hard/soft iron to a raw-sample CSV")
    fit.add_argument("csv")
    fit.add_argument("--json", action="store_true", help="print one JSON object")
    fit.add_argument("--field-ut", type=float, help="reference field magnitude (µT)")
    fit.add_argument("--model", choices=["full", "diagonal", "sphere"], default="full")
    fit.add_argument("--range-ut", type=float, help="sensor range (µT); samples at it are clipped")
    fit.add_argument("--bins", type=int, default=100, help="coverage bins (Fibonacci sphere)")
    fit.add_argument("--gain-sigma", type=float, default=FitOptions.gain_sigma,
                     help="1σ spread of the raw-to-reference field ratio (with --field-ut)")

    sub.add_parser("plugins", help="list loaded plugins and their hooks (JSON)")

    hist = sub.add_parser("history", help="show a unit's runs from a station's results store")
    hist.add_argument("serial")
    hist.add_argument("--station", help="station file naming the results store (default: demo)")

    try:
        plugins = load_plugins()  # once: its commands are needed before the arguments are parsed
    except PluginError as exc:
        _err(str(exc))
        return 2
    plugins.hook.magline_add_commands(subparsers=sub)
    args = parser.parse_args(argv)
    if hasattr(args, "handler"):
        return args.handler(args)
    handler = {"run": _run, "check": _check, "fit": _fit, "plugins": _plugins, "history": _history}
    return handler[args.command](args, plugins)


def _err(message: str) -> None:
    print(message, file=sys.stderr)


def _load(path: str | None, plugins: Plugins) -> tuple[Station, Path]:
    """Load a station file (or the embedded demo) and check the names it uses against the plugins."""
    if path is None:  # the embedded demo keeps its files in the directory magline runs in
        with as_file(files("magline.stations") / DEMO) as demo:
            text, name, where = read_station_text(demo), str(demo), Path.cwd()
    else:
        text, name, where = read_station_text(path), path, Path(path).parent
    station = load_station_text(text, name)
    problems = []
    for part, product in station.products.items():
        if product.backend not in plugins.dut_backends:
            line = line_of(text, ("products", part, "backend"))
            problems.append(f"{name}:{line}: products.{part}.backend: unknown DUT backend "
                            f"{product.backend!r}; loaded: {', '.join(sorted(plugins.dut_backends))}")
        problems += _option_problems(plugins, ("dut backend", product.backend), product.options,
                                     ("products", part, "options"), text, name)
        problems += _option_problems(plugins, ("power control", product.power.method), product.power.options,
                                     ("products", part, "power", "options"), text, name)
        if product.power.method not in plugins.power_controls:
            line = line_of(text, ("products", part, "power", "method"))
            problems.append(f"{name}:{line}: products.{part}.power.method: unknown power control "
                            f"{product.power.method!r}; loaded: {', '.join(sorted(plugins.power_controls))}")
    for key, value, registry in (("field_source.type", station.field_source.type, plugins.field_sources),
                                 ("results.sink", station.results.sink, plugins.result_sinks)):
        if value not in registry:
            line = line_of(text, tuple(key.split(".")))
            problems.append(f"{name}:{line}: {key}: unknown {key.split('.')[0].replace('_', ' ')} "
                            f"{value!r}; loaded: {', '.join(sorted(registry))}")
    if problems:
        raise StationError(problems)
    return station, where


def _option_problems(plugins: Plugins, key: tuple[str, str], options: dict, where: tuple, text: str,
                     name: str) -> list[str]:
    """A plugin's declared options model applied to the station file's options, one line per problem."""
    model = plugins.option_models.get(key)
    if model is None:
        return []
    try:
        model.model_validate(options)
    except ValidationError as exc:
        return [f"{name}:{line_of(text, (*where, *err['loc']))}: {'.'.join(map(str, (*where, *err['loc'])))}: "
                f"{err['msg']}" for err in exc.errors()]
    return []


def _run(args: argparse.Namespace, plugins: Plugins) -> int:
    from magline.core.console import OperatorConsole
    from magline.core.sequencer import Sequencer

    plugins.pm.register(OperatorConsole())
    try:
        station, where = _load(args.station, plugins)
        sequencer = Sequencer(station, plugins, where)
    except (StationError, PluginError, ValueError, KeyError, RuntimeError, OSError) as exc:
        _err(str(exc))  # includes instruments that do not answer at start-up
        return 2
    try:
        code = 0
        while True:
            serial = args.serial or _ask_serial(station, args.station is None)
            if serial is None:
                return code
            record = sequencer.run_unit(serial, args.part, args.operator)
            code = EXIT[record.verdict]
            if sequencer.stopped is not None:
                _err(f"batch stopped: {sequencer.stopped}")
                return 2
            if not args.loop:
                return code
            args.serial = None
    finally:
        sequencer.close()


def _ask_serial(station: Station, demo: bool) -> str | None:
    if demo and not sys.stdin.isatty():
        from datetime import UTC, datetime
        return "DEMO-" + datetime.now(UTC).strftime("%Y%m%d-%H%M%S")
    try:
        serial = input(f"{station.prompts.serial}: ").strip()
    except EOFError:
        return None
    return serial or None


def _check(args: argparse.Namespace, plugins: Plugins) -> int:
    try:
        station, _ = _load(args.station, plugins)
    except (StationError, PluginError) as exc:
        _err(str(exc))
        return 2
    parts = ", ".join(f"{p} ({station.limit_hash(p)})" for p in station.products)
    print(f"{args.station}: OK — station {station.station.id}, line {station.station.line}, "
          f"products {parts}")
    return 0


def _fit(args: argparse.Namespace, plugins: Plugins) -> int:
    try:
        samples = read_samples(args.csv)
        options = FitOptions(model=args.model, field_ut=args.field_ut, range_ut=args.range_ut,
                             coverage_bins=args.bins, gain_sigma=args.gain_sigma)
        if samples.applied_ut is not None:  # a coil applied known vectors: the full affine model
            result = fit_affine(samples.mag_ut, samples.applied_ut, args.field_ut)
        else:
            result = fit_calibration(samples.mag_ut, options, t_ms=samples.t_ms, temp_c=samples.temp_c)
    except SampleFileError as exc:
        _err(str(exc))
        return 2
    except FitRefused as exc:
        if args.json:
            print(json.dumps({"refused": exc.reason, "message": exc.message, "advice": exc.advice}))
        _err(f"calibration refused: {exc.message}\n{exc.advice}")
        return 1
    doc = result.to_dict()
    if args.json:
        print(json.dumps(doc))
        return 0
    print(_fit_summary(doc))
    return 0


def _fit_summary(doc: dict) -> str:
    h, hs = doc["hard_iron_ut"], doc["hard_iron_sigma_ut"]
    rows = ["    [" + ", ".join(f"{v:8.4f}" for v in row) + "]" for row in doc["soft_iron"]]
    rej = ", ".join(f"{k} {v}" for k, v in doc["samples"]["rejected"].items()) or "none"
    lines = [
        f"model        {doc['model']}",
        "hard iron    " + ", ".join(f"{v:.3f} ± {s:.3f}" for v, s in zip(h, hs, strict=True)) + " µT",
        "soft iron", *rows,
        f"field        {doc['field_ut']:.3f} µT "
        f"(data: {doc['field_estimate_ut']:.3f} ± {doc['field_sigma_ut']:.3f})",
        f"residual     rms {doc['residual_ut']['rms']:.3f} µT, max {doc['residual_ut']['max_abs']:.3f} µT",
        f"coverage     {doc['coverage']['fraction']:.0%} of {doc['coverage']['bins']} bins, heading 1σ "
        f"{doc['coverage']['direction_sigma_deg']:.3f}°",
        f"samples      {doc['samples']['used']} used of {doc['samples']['total']}; rejected: {rej}",
    ]
    if doc["raw_to_reference_ratio"] is not None:
        lines.append(f"raw/ref      {doc['raw_to_reference_ratio']:.4f}")
    if doc.get("model_misfit"):
        mis = doc["model_misfit"]
        lines.append(f"WARNING      the soft iron is not axis-aligned: the {mis['model']} model leaves "
                     f"{mis['residual_ut']:.2f} µT (full matrix {mis['full_model_residual_ut']:.2f} µT) and "
                     f"costs up to {mis['direction_error_deg']:.2f}° of heading; use --model full if the "
                     "autopilot holds a full matrix")
    return "\n".join(lines)


def _plugins(args: argparse.Namespace, plugins: Plugins) -> int:
    print(json.dumps({"plugins": plugins.describe(), "dut_backends": sorted(plugins.dut_backends),
                      "field_sources": sorted(plugins.field_sources),
                      "result_sinks": sorted(plugins.result_sinks),
                      "power_controls": sorted(plugins.power_controls)}, indent=2))
    return 0


def _history(args: argparse.Namespace, plugins: Plugins) -> int:
    try:
        station, where = _load(args.station, plugins)
        sink = plugins.result_sinks[station.results.sink](station, where)
    except (StationError, PluginError) as exc:
        _err(str(exc))
        return 2
    runs = sink.history(args.serial)
    sink.close()
    if not runs:
        print(f"no runs for {args.serial}")
        return 1
    for run in runs:
        cov = ", ".join(f"{a['coverage']:.0%}" + (" refused" if a.get("refused") else "")
                        for a in run["attempts"])
        print(f"#{run['id']} {run['started']} {run['part']} {run['verdict'].upper()} "
              f"attempts [{cov}] {run['cause'] or ''}".rstrip())
        for f in run["failed"]:
            print(f"    ✗ {f['name']} = {f['value']:.4g} {f['unit']} limits [{f['low']}, {f['high']}]")
    return 0


if __name__ == "__main__":
    sys.exit(main())
