"""``magline`` command line: run a station, check a station file, fit a CSV, list plugins, history.

Plugins add their own sub-commands through ``magline_add_commands`` (the simulators: ``sim``).

Exit codes of ``magline run``: 0 pass, 1 fail, 2 error (bad station file, no DUT, plugin error).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

from magline.core import __version__
from magline.core.faults import StationFault, UnitAborted
from magline.core.plugins import PluginError, load_plugins

if TYPE_CHECKING:
    from magline.core.plugins import Plugins
    from magline.core.station import Station

# Why so few imports above: every command starts here, and ``magline --help`` or ``magline check`` must
# answer at once; each command imports what it uses (the fit, the results store's SQLAlchemy) on use.

DEMO = "demo.yaml"
GAIN_SIGMA = 0.05  # ``magline fit``'s default, the fit's own (FitOptions.gain_sigma; a test holds them equal)


DESCRIPTION = ("Calibrate drone magnetometers at the end of a production line: run a station, check a station "
               "file, fit a CSV, read the results (history, show, export, spc, report), serve the station screen.")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="magline", description=DESCRIPTION)
    parser.add_argument("--version", action="version", version=f"magline {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    run = sub.add_parser("run", help="calibrate units on a station (default: the embedded mock demo)")
    run.add_argument("station", nargs="?", help="station file (default: the embedded demo station)")
    run.add_argument("--serial", action="append", metavar="SERIAL | SLOT=SERIAL",
                     help="unit serial (else prompt, or generated for the demo); on a station with slots, "
                          "once per slot: --serial A=SN-1 --serial B=SN-2 (slots not named are prompted for, "
                          "an empty answer leaves the slot empty)")
    run.add_argument("--part", help="part number (else the station's default)")
    run.add_argument("--operator", default="", help="operator name for the record")
    run.add_argument("--loop", action="store_true", help="keep prompting for the next serial")
    run.add_argument("--record-mavlink", metavar="FILE.tlog", type=Path,
                     help="keep every MAVLink packet between the station and each vehicle, both ways, in a tlog "
                          "(pymavlink, MAVProxy and QGroundControl read it); several links: FILE-<part or slot>.tlog")

    check = sub.add_parser("check", help="validate a station file")
    check.add_argument("station")

    fit = sub.add_parser("fit", help="fit hard/soft iron to a raw-sample CSV")
    fit.add_argument("csv")
    fit.add_argument("--json", action="store_true", help="print one JSON object")
    fit.add_argument("--field-ut", type=number_option(above=0), help="reference field magnitude (µT)")
    fit.add_argument("--model", choices=["full", "diagonal", "sphere"], default="full")
    fit.add_argument("--range-ut", type=number_option(above=0), help="sensor range (µT); samples at it are clipped")
    fit.add_argument("--bins", type=whole_number(least=4, most=10000), default=100,
                     help="coverage bins (Fibonacci sphere, 4 to 10000)")
    fit.add_argument("--gain-sigma", type=number_option(above=0, most=1), default=GAIN_SIGMA,
                     help="1σ spread of the raw-to-reference field ratio (with --field-ut)")
    fit.add_argument("--run", help="a magline export --raw file: the run to fit (its UUID or first characters)")
    fit.add_argument("--serial", help="a magline export --raw file: the serial whose run to fit")
    fit.add_argument("--attempt", type=int, help="a magline export --raw file: this attempt (else the accepted one)")
    fit.add_argument("--sensor", help="a magline export --raw file: this magnetometer (mag1, the primary, by default; "
                                      "mag2, mag3 as in the measurements)")
    fit.add_argument("--with-refused", action="store_true",
                     help="a magline export --raw file: pool refused attempts too")

    listing = sub.add_parser("plugins", help="list loaded plugins and their hooks (JSON)")
    listing.add_argument("--options", action="store_true",
                         help="print the options each plugin takes in a station file (Markdown tables)")

    sync = sub.add_parser("sync", help="forward the station's queued records to its results server")
    sync.add_argument("--station", help="station file naming the results store (default: demo)")

    show = sub.add_parser("show", help="a run's whole record (by run id, UUID, or serial: its latest run)")
    show.add_argument("run", help="run id, UUID, or serial")
    show.add_argument("--station", help="station file naming the results store (default: demo)")
    show.add_argument("--json", action="store_true", help="one JSON object")

    exp = sub.add_parser("export", help="stream runs from the results store as CSV or JSON lines")
    exp.add_argument("--station", help="station file naming the results store (default: demo)")
    _run_filter_arguments(exp, "part number")
    exp.add_argument("--verdict", type=str.lower, choices=["pass", "fail", "error", "aborted", "incomplete", "running"],
                     help="one verdict's runs (in any case: PASS, pass)")
    exp.add_argument("--serial", help="one unit's runs (whatever the case it is typed in)")
    exp.add_argument("--format", choices=["csv", "jsonl"], default="csv")
    exp.add_argument("--raw", action="store_true",
                     help="every stored raw sample (CSV: a row per sample); an attempt that read past "
                          "acquisition.samples short of its coverage is stored thinned to that many")

    from magline.core.quality.trends import shifts_argument
    from magline.core.results.instants import instant_argument, until_argument

    spc = sub.add_parser("spc", help="control charts, Cpk / Ppk, yield and refusal causes of a part's latest units")
    spc.add_argument("--station", help="station file naming the results store and the limits (default: demo)")
    _run_filter_arguments(spc, "part number (default: the station's default or only part)")
    spc.add_argument("--measurement", action="append", metavar="NAME", help="only these measurements (repeat)")
    spc.add_argument("--last", type=whole_number(least=1, most=10**9), default=10_000,
                     help="the latest N runs (default 10000)")
    spc.add_argument("--baseline", type=whole_number(least=2, most=10**9), default=50,
                     help="the first N judged units set the centre line and limits (provisional ones; with --freeze: "
                          "the baseline frozen; default 50)")
    spc.add_argument("--freeze", action="store_true",
                     help="Phase I: establish limits from a baseline (the first --baseline judged units, or those "
                          "between --baseline-since and --baseline-until), check its stability and store them, "
                          "versioned, in the results store; every later spc judges units against them")
    spc.add_argument("--baseline-since", type=instant_argument, metavar="WHEN", help="a baseline by date: its start")
    spc.add_argument("--baseline-until", type=until_argument, metavar="WHEN",
                     help="a baseline by date: its end (a date: that day included)")
    spc.add_argument("--by", metavar="NAME", help="with --freeze (required): who is responsible for the limits")
    spc.add_argument("--exclude", action="append", metavar="SERIAL",
                     help="with --freeze: leave this unit out of the baseline (its cause known; repeat)")
    spc.add_argument("--accept-unstable", action="store_true",
                     help="with --freeze: freeze a baseline whose own charts signal (needs --reason)")
    spc.add_argument("--reason", metavar="TEXT", help="with --accept-unstable: why, kept with the version")
    spc.add_argument("--html", metavar="FILE", help="also write the charts as one self-contained HTML page")
    spc.add_argument("--with-reports", action="store_true",
                     help="with --html: also write the unit report of every charted unit that has none yet (into the "
                          "station's results.reports folder, else <FILE>-reports/ beside the page), so that a click "
                          "on any point opens one")
    spc.add_argument("--shifts", type=shifts_argument, metavar="HH:MM,…",
                     help="the line's shift starts (e.g. 06:00,14:00,22:00, local time): yield and failure trends per "
                          "shift instead of per day")
    spc.add_argument("--json", action="store_true", help="print the report as one JSON object (per measurement: "
                     "chart kind, n, centre, limits, capability and its method, signals, and every point with "
                     "its unit's serial, run and time)")
    spc.add_argument("--csv", action="store_true", help="print every charted point as CSV: measurement, serial, run, "
                                                        "time, value, moving range, the chart's lines, the signals")
    rep = sub.add_parser("report", help="one self-contained HTML report of a run (by run id, UUID or serial)")
    rep.add_argument("run", metavar="RUN_ID|SERIAL")
    rep.add_argument("--station", help="station file naming the results store (default: demo)")
    rep.add_argument("-o", "--output", metavar="FILE", help="where to write it (default: <serial>-run<id>.html)")
    scr = sub.add_parser("station", help="serve the station screen: operators run units from a browser")
    scr.add_argument("station", nargs="?", help="station file (default: the embedded demo)")
    scr.add_argument("--host", default="127.0.0.1", help="address to bind (any other than loopback needs the token)")
    scr.add_argument("--port", type=port_number, default=8080, help="TCP port (0: any free one, announced)")
    dash = sub.add_parser("dashboard", help="the line's page, read-only over the results store: every station live, "
                                            "the process, any unit by serial")
    given = dash.add_mutually_exclusive_group()
    given.add_argument("--station", help="station file whose results store to read (default: the embedded demo's)")
    given.add_argument("--store", help="a results store itself: a SQLite file, or a database URL "
                                       "(postgresql+psycopg://role:password@host/db, a role that can only read)")
    dash.add_argument("--host", default="127.0.0.1", help="address to bind (any other than loopback needs the token)")
    dash.add_argument("--port", type=port_number, default=8090, help="TCP port (0: any free one, announced)")
    from magline.core.quality.trends import shifts_argument

    dash.add_argument("--shifts", type=shifts_argument, default=None, metavar="HH:MM,…",
                      help="the line's shift starts (tiles count the running shift; default: the station file's, "
                           "else the day)")
    held = sub.add_parser("slots", help="which station holds which slot now, from the results store every "
                                        "computer of the line shares")
    held.add_argument("--station", help="station file naming the results store (default: demo)")
    ports = sub.add_parser("ports", help="serial ports plugged in, by the names a station file uses (udev's by-path: "
                                         "the fixture's port; by-id: the board's USB serial)")
    ports.add_argument("--root", help="a folder laid out as /dev/serial is (default /dev/serial)")
    ports.add_argument("--json", action="store_true", help="one JSON object per port")
    hist = sub.add_parser("history", help="show a unit's runs from a station's results store")
    hist.add_argument("serial")
    hist.add_argument("--station", help="station file naming the results store (default: demo)")

    try:
        # once: its commands are needed before the arguments are parsed; what the plugins register (their
        # options models) only once they are (``--help`` uses none of it)
        plugins = load_plugins(register=False)
    except PluginError as exc:
        _err(str(exc))
        return 2
    plugins.hook.magline_add_commands(subparsers=sub)
    args = parser.parse_args(argv)
    try:
        plugins.register()
    except PluginError as exc:
        _err(str(exc))
        return 2
    since, until = getattr(args, "since", None), getattr(args, "until", None)
    if since and until and since >= until:  # both in the stored form: the same zone and layout, so ordered as text
        _err(f"--since {since} is not before --until {until}: no run can start in that window (swapped?)")
        return 2
    if hasattr(args, "handler"):  # a plugin's command: its reader may go away too
        return _quiet_broken_pipe(lambda: args.handler(args))
    handler = {"run": _run, "check": _check, "fit": _fit, "plugins": _plugins, "history": _history,
               "show": _show, "export": _export, "sync": _sync, "spc": _spc, "report": _report,
               "station": _station, "slots": _slots, "ports": _ports, "dashboard": _dashboard}
    return _quiet_broken_pipe(lambda: handler[args.command](args, plugins))


def _run_filter_arguments(parser: argparse.ArgumentParser, part_help: str) -> None:
    """Which runs a reading command looks at (``RunFilter``)."""
    from magline.core.results.instants import instant_argument, until_argument

    when = ("an ISO time (a time without offset is this computer's local time; Z or +01:00 say otherwise), "
            "a date, today, yesterday, or a time ago: 8h, 7d")
    parser.add_argument("--since", type=instant_argument, help=f"runs started at or after: {when}")
    parser.add_argument("--until", type=until_argument, help=f"runs started before: {when} (a date: that day "
                                                           "included)")
    parser.add_argument("--part", help=part_help)
    parser.add_argument("--station-id", help="only this writing station's runs (a shared store holds several)")


def _err(message: str) -> None:
    from magline.core.text import for_terminal

    print(for_terminal(message, sys.stderr), file=sys.stderr)


def _load(path: str | None, plugins: Plugins) -> tuple[Station, Path]:
    """Load a station file (or the embedded demo) and check the names it uses against the plugins;
    every problem is reported at once."""
    from magline.core.station import StationError, read_station_text, station_problems

    if path is None:  # the embedded demo keeps its files in the directory magline runs in
        from importlib.resources import as_file, files

        with as_file(files("magline.stations") / DEMO) as demo:
            text, name, where = read_station_text(demo), str(demo), Path.cwd()
    else:
        text, name, where = read_station_text(path), path, Path(path).parent
    station, problems = station_problems(text, name, plugins)
    if problems or station is None:
        raise StationError(problems)
    return station, where


def _not_used(refused: str | None) -> str:
    """Why an attempt was not used, in one word for the history line: a tumble cut short (timeout,
    lost link, abort) was never judged, so it is not called refused."""
    if not refused:
        return ""
    if refused.startswith("interrupted"):
        return " cut short"
    return " low coverage" if refused.startswith("coverage") else " refused"


def _run(args: argparse.Namespace, plugins: Plugins) -> int:
    """Run units until the batch ends: one unit, or with ``--loop`` until an empty serial / EOF.

    Ctrl-C or SIGTERM aborts the unit under test (its DUT restored where the link allows, its
    record marked aborted) and ends the batch with its summary; no traceback.
    """
    from magline.core.operator_ui.console import OperatorConsole
    from magline.core.sequencer import Sequencer
    from magline.core.sequencer.batch import Batch
    from magline.core.sequencer.hold import StationBusy
    from magline.core.serials import Refused, known_part
    from magline.core.station import StationError

    console = OperatorConsole()
    plugins.pm.register(console)
    taps: list[Any] = []
    try:
        station, where = _load(args.station, plugins)
        if args.record_mavlink is not None:
            station, taps = _tap_links(station, args.record_mavlink)
        sequencer = Sequencer(station, plugins, where)
    except (StationError, PluginError, StationFault, ValueError, KeyError, RuntimeError, OSError) as exc:
        _err(str(exc))  # includes instruments that do not answer at start-up
        for tap in taps:
            tap.close()
        return 2
    batch = Batch()
    global _terminal_scans
    if args.loop and sys.stdin.isatty():  # scans typed while a unit runs are queued and said, not echoed
        from magline.core.operator_ui.scans import TerminalScans

        _terminal_scans = TerminalScans(console.note)
    try:
        if args.part is not None:  # a part the station does not build: refused before a serial is asked
            known_part(args.part, list(station.products), station.station.id)
        units = _slot_batches(args, station) if station.slots else (
            {"": serial} for serial in _serials(args, station))
        with sequencer.abort.signals():
            try:
                for unit in units:
                    try:
                        if station.slots:
                            from magline.core.sequencer.slots import SlotRunner

                            records = SlotRunner(sequencer).run(unit, args.operator)
                            if not records:
                                break
                        else:
                            records = [sequencer.run_unit(unit[""], args.part, args.operator)]
                    except (Refused, StationBusy) as exc:  # nothing recorded: say why, take the next scan
                        _err(str(exc))
                        if not args.loop:
                            return 2
                        continue
                    for record in records:
                        batch.add(record)
                        for fault in record.listener_faults:  # the verdict stands; the plugin's author is told
                            _err(f"warning: a listener failed on {record.serial}: {fault}")
                    if sequencer.abort.requested is not None:
                        break
                    if sequencer.stopped is not None:
                        _err(f"batch stopped: {sequencer.stopped}")
                        break
            except UnitAborted as exc:  # at the serial prompt: nothing to restore
                console.note(f"{exc.reason}: no unit under test")
                if batch.units == 0:
                    return 2  # that one line says it all
    except ValueError as exc:  # --serial that does not fit the station
        _err(str(exc))
        return 2
    finally:
        sequencer.close()
        for tap in taps:
            tap.close()
            print(f"MAVLink traffic: {tap.tlog} ({tap.log.packets} packets)", file=sys.stderr)
        if _terminal_scans is not None:
            _terminal_scans.close()
            _terminal_scans = None
    if batch.units == 0:
        _err("no unit tested")
        return 2
    if args.loop or batch.units > 1 or sequencer.abort.requested is not None:
        console.batch_summary(batch)
    return batch.exit_code()


def _tap_links(station: Station, tlog: Path) -> tuple[Station, list[Any]]:
    """The station with each MAVLink link pointed at a recording proxy, and the proxies."""
    from magline.core.links.mavlink_tap import MavlinkTap, can_tap

    links = [(part, p.connection) for part, p in station.products.items() if can_tap(p.connection)]
    links += [(slot.id, slot.connection) for slot in station.slots if slot.connection and can_tap(slot.connection)]
    if not links:
        raise ValueError(f"--record-mavlink: station {station.station.id} has no tcp: or udpout:// MAVLink link")
    taps: dict[str, Any] = {}
    for name, connection in links:
        path = tlog if len(links) == 1 else tlog.with_name(f"{tlog.stem}-{name}{tlog.suffix or '.tlog'}")
        taps[name] = MavlinkTap(connection, path)
    products = {part: p.model_copy(update={"connection": taps[part].connection}) if part in taps else p
                for part, p in station.products.items()}
    slots = [slot.model_copy(update={"connection": taps[slot.id].connection}) if slot.id in taps else slot
             for slot in station.slots]
    return station.model_copy(update={"products": products, "slots": slots}), list(taps.values())


def _slot_batches(args: argparse.Namespace, station: Station) -> Iterator[dict[str, str]]:
    """Slot id → serial for each load of the fixture: the ``--serial SLOT=SERIAL`` given (slots not
    named stay empty), else the operator is asked slot by slot (an empty answer leaves the slot
    empty); with ``--loop`` asked again for each next load, until every slot is left empty."""
    from magline.core.serials import clean_serial
    from magline.core.station.checks import did_you_mean

    ids = [slot.id for slot in station.slots]
    given: dict[str, str] = {}
    for item in args.serial or []:
        slot, sep, serial = item.partition("=")
        if not sep:
            raise ValueError(f"station {station.station.id} has slots ({', '.join(ids)}): "
                             f"give --serial SLOT=SERIAL, not {item!r}")
        if slot.strip() not in ids:
            raise ValueError(f"--serial {item}: no slot {slot.strip()!r} on station {station.station.id} "
                             f"(slots: {', '.join(ids)}){did_you_mean(slot.strip(), ids)}")
        given[slot.strip()] = clean_serial(serial, station.slot_product(station.slot(slot.strip())))
    if given:  # a label given for two slots is refused by the slot runner, before anything is recorded
        yield given
        if not args.loop:
            return
    while (load := _ask_slots(station)) is not None:
        yield load
        if not args.loop:
            return


def _ask_slots(station: Station) -> dict[str, str] | None:
    """One serial per slot from the operator (or a scanner); None when every slot is left empty."""
    from magline.core.serials import SerialRefused, clean_serial, one_serial_per_slot

    load: dict[str, str] = {}
    for slot in station.slots:
        while True:
            try:
                typed = _ask(f"slot {slot.id} ({slot.part}) — {station.prompts.serial} (empty: no unit): ")
            except EOFError:
                return load if any(load.values()) else None
            try:
                load[slot.id] = clean_serial(typed, station.slot_product(slot)) if typed.strip() else ""
                one_serial_per_slot(load)  # a label scanned twice is asked again at once, for this slot
                break
            except SerialRefused as exc:  # nothing recorded: say the rule and ask this slot again
                load.pop(slot.id, None)
                _err(str(exc))
    return load if any(load.values()) else None


def _serials(args: argparse.Namespace, station: Station) -> Iterator[str]:
    """The units to test: ``--serial`` first, then (with ``--loop``) one per line the operator or a
    barcode scanner types, until an empty line or EOF.  Only the embedded demo without a terminal
    and without ``--loop`` invents one serial, so ``magline run`` works in a plain script."""
    if args.serial and len(args.serial) > 1:
        raise ValueError(f"station {station.station.id} has no slots: give one --serial")
    if args.serial:
        yield args.serial[0]
    elif args.station is None and not args.loop and not sys.stdin.isatty():
        from datetime import UTC, datetime
        yield "DEMO-" + datetime.now(UTC).strftime("%Y%m%d-%H%M%S")
    elif (serial := _ask_serial(station)) is not None:
        yield serial
    else:
        return
    while args.loop and (serial := _ask_serial(station)) is not None:
        yield serial


_terminal_scans: Any = None  # ``--loop`` on a terminal: core.operator_ui.scans.TerminalScans


def _ask(prompt: str) -> str:
    """``input`` that ends its line on a pipe too: a terminal echoes the operator's Enter, a pipe
    (a scanner script, a log) does not, and the next line would run on after the prompt.  With
    ``--loop`` on a terminal the answer comes from the scans read meanwhile (``TerminalScans``)."""
    if _terminal_scans is not None:
        return _terminal_scans.ask(prompt)
    piped = not sys.stdin.isatty()
    try:
        typed = input(prompt)
    except EOFError:  # the end of the scans: the prompt's line ends before what follows
        if piped:
            print(flush=True)
        raise
    if piped:
        print(typed, flush=True)
    return typed


def _ask_serial(station: Station) -> str | None:
    try:
        serial = _ask(f"{station.prompts.serial}: ").strip()
    except EOFError:
        return None
    return serial or None


def _check(args: argparse.Namespace, plugins: Plugins) -> int:
    from magline.core.station import StationError

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
    from magline.core.fit import FitOptions, FitRefused, fit_calibration
    from magline.core.fit.affine import fit_affine
    from magline.core.fit.samples_csv import SampleFileError, parse_samples, select_export_rows

    try:
        text, chosen = select_export_rows(_read_text(args.csv), args.csv, args.run, args.serial, args.attempt,
                                          args.with_refused, args.sensor)
        samples = parse_samples(text, args.csv)
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
    doc["fitted"] = chosen or args.csv
    doc["field_from"] = "--field-ut" if args.field_ut else "the readings' own radius (no --field-ut given)"
    if args.json:
        print(json.dumps(doc))
        return 0
    if chosen:
        print(f"fitted       {chosen}")
    print(_fit_summary(doc))
    if not args.field_ut:
        print(f"field from   the readings' own radius, {doc['field_ut']:.3f} µT (give --field-ut to normalise "
              "to the reference)")
    return 0


def _read_text(path: str) -> str:
    from magline.core.fit.samples_csv import SampleFileError

    try:
        return Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise SampleFileError(f"{path}: cannot read: {exc.strerror}") from exc


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
    if doc.get("drift"):
        lines.append(f"warm-up      {_drift_words(doc['drift'])}")
    if doc.get("model_misfit"):
        mis = doc["model_misfit"]
        lines.append(f"WARNING      the soft iron is not axis-aligned: the {mis['model']} model leaves "
                     f"{mis['residual_ut']:.2f} µT (full matrix {mis['full_model_residual_ut']:.2f} µT) and "
                     f"costs up to {mis['direction_error_deg']:.2f}° of heading; use --model full if the "
                     "autopilot holds a full matrix")
    return "\n".join(lines)


def _drift_words(drift: dict) -> str:
    """What the fit's warm-up drift test decided, in a line: a quality engineer must tell "no drift"
    from "could not judge"."""
    from magline.core.fit.geometric import DRIFT_SEPARATION_MIN

    if not drift.get("judged", True) and drift.get("separation", 0.0) >= DRIFT_SEPARATION_MIN:
        return "not judged: the drift model could not be fitted to these readings"
    if not drift.get("judged", True):
        return (f"not judged: these readings cannot tell an offset drift from soft iron (separation "
                f"{drift.get('separation', 0.0):.1f}; tumble on past the sweep's turn)")
    if drift.get("unresolved") and drift.get("warm_up_excluded"):
        return (f"DRIFT NOT CLEARED: a drift was found, the first {drift['warm_up_excluded']} readings set aside, "
                "and whether the rest still drift could not be judged; the offset may be bent by it")
    if drift.get("unresolved"):
        return (f"DRIFT NOT REMOVED: a drift was found (statistic {drift['statistic']:.1f} > {drift['threshold']:.1f}) "
                "but the readings could neither set it aside nor model it; the offset may be bent by it")
    if drift.get("modelled"):
        return "a drift throughout: modelled, the offset given is the end state"
    if drift.get("warm_up_excluded"):
        return f"drift at the start: the first {drift['warm_up_excluded']} readings set aside"
    if drift.get("statistic") is None:
        return "not judged"
    blind = f"; a drift under {drift['detectable_ut']:.1f} µT would not show" if "detectable_ut" in drift else ""
    return f"no drift (statistic {drift['statistic']:.1f} ≤ {drift['threshold']:.1f}{blind})"


def _plugins(args: argparse.Namespace, plugins: Plugins) -> int:
    if args.options:
        from magline.core.station.options_reference import options_reference

        print(options_reference(plugins), end="")
        return 0
    print(json.dumps({"plugins": plugins.describe(), "registered": plugins.registry(),
                      "dut_backends": sorted(plugins.dut_backends),
                      "field_sources": sorted(plugins.field_sources),
                      "result_sinks": sorted(plugins.result_sinks),
                      "power_controls": sorted(plugins.power_controls), "motions": sorted(plugins.motions),
                      "current_sources": sorted(plugins.current_sources)},
                     indent=2))
    return 0


def _ports(args: argparse.Namespace, plugins: Plugins) -> int:
    """What is plugged in, each port with the names to write in a station file (``serial:NAME:BAUD``)."""
    from dataclasses import asdict

    from magline.core.links.serial_port import UDEV_ROOT, list_ports

    root = Path(args.root) if args.root else UDEV_ROOT
    found = list_ports(root)
    if args.json:
        for port in found:
            print(json.dumps(asdict(port)))
        return 0 if found else 1
    if not found:
        print(f"no serial port is plugged in (nothing under {root}); a flight controller on USB appears as "
              "/dev/ttyACM0 with udev's names under /dev/serial (docs/connecting-units.md)")
        return 1
    print(f"{len(found)} serial port{'s' if len(found) > 1 else ''} ({root}); name a slot by its port, "
          "a unit by its board:")
    for port in found:
        print(f"  {port.device}" + (f"  {port.description}" if port.description else ""))
        if port.by_path:
            print(f"    port   {port.by_path}")
        if port.by_id:
            print(f"    board  {port.by_id}")
    return 0


def _history(args: argparse.Namespace, plugins: Plugins) -> int:
    from magline.core.results.sinks import close_sink, open_results
    from magline.core.station import StationError
    from magline.core.text import fmt, percent

    try:
        station, where = _load(args.station, plugins)
    except (StationError, PluginError) as exc:
        _err(str(exc))
        return 2
    missing = _missing_store(args, station, where)
    if missing is not None:
        _err(missing)
        return 1
    try:
        sink = open_results(station, where, plugins, main_only=True)
    except (StationFault, ValueError) as exc:
        _err(str(exc))
        return 2
    try:
        args.serial = args.serial.strip()  # a scanned or pasted serial with its spaces finds the unit
        runs = sink.history(args.serial)
    finally:
        close_sink(sink)
    if not runs:
        print(f"no runs for {args.serial}")
        return 1
    for run in runs:
        cov = ", ".join(percent(a["coverage"]) + _not_used(a.get("refused")) for a in run["attempts"])
        where_aborted = f" during {run['aborted_phase']}" if run.get("aborted_phase") else ""
        cal = run.get("calibration") or {}
        offsets = (" offset [" + ", ".join(fmt(v) for v in cal["hard_iron_ut"]) + "] µT") if cal.get(
            "hard_iron_ut") else ""
        started = re.sub(r"\.\d+(?=[+-]\d\d:\d\d$|Z$)", "", str(run["started"]))  # to the second, with its offset
        print(f"#{run['id']} {started} station {run['station_id']} {run['part']} "
              f"{run['verdict'].upper()}{where_aborted}{offsets} attempts [{cov}] {run['cause'] or ''}".rstrip())
        for f in run["failed"]:
            print(f"    ✗ {f['name']} = {fmt(f['value'], f['unit'])}  limits [{fmt(f['low'])}, {fmt(f['high'])}]")
    return 0


def _missing_store(args: argparse.Namespace, station: Station, where: Path) -> str | None:
    """Reading never creates a store: why there is nothing to read, or None (the store it reads is said)."""
    from magline.core.results.sqlite_store import results_path

    if station.main_results.sink != "sqlite":
        return None
    path = results_path(station, where)
    name = "the embedded demo station" if args.station is None else args.station
    if not path.exists():
        return f"no results store at {path} (named by {name}); nothing has been recorded there yet"
    print(f"results store {path} (named by {name})", file=sys.stderr)
    return None


def _open_store(args: argparse.Namespace, plugins: Plugins) -> tuple[Station, Path, Any]:
    """The station, its folder and its results store, for commands that read it (never created by reading)."""
    from magline.core.results.sinks import open_results

    station, where = _load(args.station, plugins)
    missing = _missing_store(args, station, where)
    if missing is not None:
        raise StationFault(missing)
    return station, where, open_results(station, where, plugins, main_only=True)


def _sync(args: argparse.Namespace, plugins: Plugins) -> int:
    """Forward what a station's outbox holds (the station loop does it too, after every unit)."""
    from magline.core.results.contract import ForwardsQueued
    from magline.core.results.sinks import open_results
    from magline.core.station import StationError

    try:
        station, where = _load(args.station, plugins)
        sink = open_results(station, where, plugins, main_only=True)
    except (StationError, PluginError, StationFault, ValueError) as exc:
        _err(str(exc))
        return 2
    try:
        if not isinstance(sink, ForwardsQueued):
            print("this station writes straight into its results store: nothing to forward")
            return 0
        done, pending = sink.forward()
        print(f"forwarded {done} record(s) to {sink.server}")
        if pending:
            _err(f"{pending} record(s) still queued ({sink.last_error or 'not forwarded yet'})")
            return 1
        return 0
    finally:
        sink.close()


def _with_store(args: argparse.Namespace, plugins: Plugins, use: Callable[..., int]) -> int:
    """Open the station's results store for reading, hand it to ``use`` (with the station and its
    folder when ``use`` takes them), close it."""
    from sqlalchemy.exc import SQLAlchemyError

    from magline.core.results.store import reason
    from magline.core.station import StationError

    try:
        station, where, store = _open_store(args, plugins)
    except (StationError, PluginError, StationFault) as exc:
        _err(str(exc))
        return 2
    try:
        return use(store, station, where)
    except StationFault as exc:
        _err(str(exc))
        return 2
    except SQLAlchemyError as exc:  # a store that fails while being read: its words, never a traceback
        _err(f"results store {getattr(store, 'where', '')}: {reason(exc)} — if the file is damaged, restore it "
             "from a backup")
        return 2
    finally:
        store.close()


def _slots(args: argparse.Namespace, plugins: Plugins) -> int:
    """Every slot claimed in the store, with its holder: what a line lead checks before a second PC
    starts on the same station file."""
    from magline.core.results.contract import ClaimsSlots

    def use(store: Any, *_: Any) -> int:
        if not isinstance(store, ClaimsSlots):
            print(f"results store {getattr(store, 'where', '')} keeps no slot claims")
            return 0
        rows = store.slots_held()
        if not rows:
            print("no slot is held")
        for r in rows:
            where = f"station {r['station_id']}" + (f" slot {r['slot']}" if r["slot"] else "")
            print(f"{where}: serial {r['serial']} on {r['host']} (pid {r['pid']}) since {r['since']}, seen "
                  f"{r['heartbeat']}")
        return 0

    return _with_store(args, plugins, use)


def _show(args: argparse.Namespace, plugins: Plugins) -> int:
    from magline.core.results.commands import show

    return _with_store(args, plugins, lambda store, *_: show(store, args.run.strip(), args.json))


def _export(args: argparse.Namespace, plugins: Plugins) -> int:
    from magline.core.results.commands import export
    from magline.core.results.reading import RunFilter

    where = RunFilter(since=args.since, until=args.until, part=args.part, station_id=args.station_id,
                      verdict=args.verdict, serial=args.serial)
    return _with_store(args, plugins, lambda store, *_: export(store, where, args.format, args.raw))


def _spc(args: argparse.Namespace, plugins: Plugins) -> int:
    from magline.core.lazy import warm_imports
    from magline.core.quality.commands import spc

    # the capability's statistics (a third of a second) imported while the store is opened and checked (half a
    # second of SQLite's integrity check, which releases the interpreter's lock): on a second core, at once
    warm_imports("scipy.stats")
    return _with_store(args, plugins, lambda store, station, where: spc(store, station, args, Path(where),
                                                                       plugins.measurements))


def _report(args: argparse.Namespace, plugins: Plugins) -> int:
    from magline.core.reports.commands import report

    return _with_store(args, plugins, lambda store, station, _: report(store, station, args.run.strip(), args.output))


def _station(args: argparse.Namespace, plugins: Plugins) -> int:
    from magline.core.operator_ui.screen.serve import serve
    from magline.core.station import StationError

    try:
        station, where = _load(args.station, plugins)
    except (StationError, PluginError) as exc:
        _err(str(exc))
        return 2
    return serve(station, where, plugins, args.host, args.port)


def _dashboard(args: argparse.Namespace, plugins: Plugins) -> int:
    from magline.core.dashboard.serve import serve, station_store
    from magline.core.quality.trends import Shifts
    from magline.core.station import StationError

    shifts = args.shifts
    if args.store:
        target = args.store
    else:
        try:
            station, where = _load(args.station, plugins)
            target = station_store(station, where)
        except (StationError, PluginError, StationFault) as exc:
            _err(str(exc))
            return 2
        shifts = shifts or Shifts.parse(station.station.shifts)
    return serve(target, shifts or Shifts(), args.host, args.port)


def number_option(*, above: float | None = None, least: float | None = None,
                  most: float | None = None) -> Callable[[str], float]:
    """An argparse type: a number within the bounds given, else the option's error says which.  Why: a value
    no calculation can take (a negative field for ``magline fit``, a negative speed for a simulator) went on to
    a traceback deep in the arithmetic, or to a board that never turned."""
    if least is not None and most is not None:
        words = f"between {least:g} and {most:g}"
    else:
        words = " and ".join([*([f"above {above:g}"] if above is not None else []),
                              *([f"at least {least:g}"] if least is not None else []),
                              *([f"at most {most:g}"] if most is not None else [])])

    def number(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
        if not (value == value and (above is None or value > above) and (least is None or value >= least)
                and (most is None or value <= most)):
            raise argparse.ArgumentTypeError(f"{text} is not {words}")
        return value

    return number


def whole_number(*, least: int, most: int) -> Callable[[str], int]:
    """An argparse type: a whole number from ``least`` to ``most``."""
    def number(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
        if not least <= value <= most:
            raise argparse.ArgumentTypeError(f"{value} is not between {least} and {most}")
        return value

    return number


def port_number(text: str) -> int:
    """``--port``: a TCP port, 0 for any free one.  Why checked here: a number past 65535 was bound modulo
    65536 by the resolver, and the screen announced a port it was not on."""
    try:
        port = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a port number") from None
    if not 0 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"{port} is not a TCP port (0 to 65535; 0: any free one)")
    return port


def _quiet_broken_pipe(handler: Callable[[], int]) -> int:
    """``magline fit … | head``: the reader went away; stop quietly, as a Unix filter does."""
    try:
        return handler()
    except BrokenPipeError:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # the interpreter's final flush must not fail again
        return 0


if __name__ == "__main__":
    sys.exit(main())
