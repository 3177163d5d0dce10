"""``magline sim px4|ardupilot|inav|coil|gimbal|turntable|load``: run a simulator on a real socket until
Ctrl-C / SIGTERM.

The first line printed names the address it listens on, so a script (or a person in another
terminal) knows where to point the station.  The simulator itself is imported only when the
command runs.  The command comes through its own ``sim`` entry point in the ``magline`` group
(``magline_add_commands``), as any plugin's command does: the core CLI knows nothing of simulators,
and the mock DUT plugin (an in-process unit) has nothing to do with them.
"""

from __future__ import annotations

import argparse
import errno
import re
import signal
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from magline.core.cli import number_option
from magline.core.plugins import hookimpl

POSITIVE, NOT_NEGATIVE, DIP = number_option(above=0), number_option(least=0), number_option(least=-90, most=90)


@hookimpl
def magline_add_commands(subparsers: Any) -> None:
    add_sim_command(subparsers)


def add_sim_command(subparsers: argparse._SubParsersAction) -> None:
    """``magline sim FLAVOUR``: one sub-command per simulator, each listing its own options only."""
    sim = subparsers.add_parser("sim", help="run a simulator: a flight controller (MAVLink), a Helmholtz coil with "
                                            "its fluxgate or a gimbal (SCPI)")
    flavours = sim.add_subparsers(dest="flavour", required=True,
                                  metavar="{px4,ardupilot,inav,coil,gimbal,turntable,load}")
    board = argparse.ArgumentParser(add_help=False)  # what both flight controllers take
    board.add_argument("--workdir", help="where the board keeps its parameter storage (default: a folder of its own "
                                         "under the system's temporary folder, named for the simulator and its "
                                         "address; the storage file is said when it starts)")
    board.add_argument("--mags", type=int, default=1, choices=[1, 2, 3], help="number of magnetometers (inav: 1)")
    board.add_argument("--boot-time", type=NOT_NEGATIVE, default=2.0, help="seconds silent after a reboot (default 2)")
    board.add_argument("--motion",
                       help="comma list, one per acquisition (tumble, single_axis, gimbal, two_axis: a two-axis "
                            "gimbal at constant rates, still, shared); last repeats (default: tumble, or shared with "
                            "--gimbal)")
    board.add_argument("--gimbal", metavar="tcp:HOST:PORT",
                       help="the board is mounted on this gimbal simulator and moves with it (motion 'shared')")
    board.add_argument("--turntable", metavar="tcp:HOST:PORT",
                       help="the board sits in the cradle of this turntable simulator and moves with it (motion "
                            "'shared')")
    board.add_argument("--speed", type=POSITIVE, default=1.0, help="tumble speed factor")
    board.add_argument("--field-ut", type=POSITIVE, default=48.0, help="local field magnitude (µT)")
    board.add_argument("--inclination-deg", type=DIP, default=62.0)
    board.add_argument("--noise-ut", type=NOT_NEGATIVE, default=0.3)
    board.add_argument("--mag-rate", type=POSITIVE, metavar="HZ",
                       help="how often the sensors publish a new reading (default: ardupilot and inav 10 Hz, px4 per "
                            "driver); "
                            "a faster stream repeats readings, as real vehicles do")
    board.add_argument("--seed", type=int, default=7, help="seed of the sensors' distortion and noise")
    board.add_argument("--supply", metavar="tcp:HOST:PORT",
                       help="also run a simulated SCPI bench supply that powers this board (it starts off)")
    board.add_argument("--supply-fault", choices=["dead_board", "short", "output_error"])
    board.add_argument("--load", metavar="tcp:HOST:PORT",
                       help="also run a simulated SCPI electronic load in this board's power path, downstream of its "
                            "current sensor (its input on clamps the unit still, as for the current sweep)")
    board.add_argument("--load-fault", choices=["no_sink"], help="the load's input reports on but nothing flows")
    board.add_argument("--load-rating", type=POSITIVE, default=60.0, metavar="A",
                       help="the load's largest current (default 60 A)")
    board.add_argument("--usb-powered", action="store_true",
                       help="the board takes its power from its USB port: a supply cut does not reboot it, the "
                            "hub port's power does (--usb-hub)")
    board.add_argument("--usb-hub", metavar="tcp:HOST:PORT",
                       help="also run a simulated USB hub (location 1-1) with this board on --hub-port, switched by "
                            "the stand-in uhubctl: MAGLINE_SIM_USB_HUB=tcp:HOST:PORT python -m magline.sim.uhubctl")
    board.add_argument("--hub-port", type=int, default=1, help="the hub port the board is on (default 1)")
    board.add_argument("--usb-alias", action="append", default=[], metavar="PATH",
                       help="with --listen serial:PATH: another link to the same port, kept as the first is (a udev "
                            "by-id name beside the by-path one); repeat for several")
    px4 = flavours.add_parser("px4", parents=[board], help="a simulated PX4 flight controller (MAVLink)")
    px4.add_argument("--listen", default="udp:127.0.0.1:14550",
                     help="udp:HOST:PORT, tcp:HOST:PORT (default udp:127.0.0.1:14550; port 0 picks a free one) or "
                          "serial:PATH[:BAUD] (a pseudo-terminal linked at PATH: USB without a baud, a UART at BAUD)")
    add_fault_option(px4, "px4")
    px4.add_argument("--firmware", default="1.15.0", help="firmware version (ODIAG from 1.12)")
    px4.add_argument("--untagged", action="store_true",
                     help="report version 0.0.0, as a build from an untagged tree (SITL) does")
    px4.add_argument("--no-shell", action="store_true",
                     help="the MAVLink shell answers nothing, as on POSIX builds (SITL)")
    px4.add_argument("--preset-ids", action="store_true",
                     help="CAL_MAGn_ID preset to the detected sensors, as POSIX startup scripts do")
    ardupilot = flavours.add_parser("ardupilot", parents=[board], help="a simulated ArduPilot flight controller "
                                                                        "(MAVLink)")
    ardupilot.add_argument("--listen", default="tcp:127.0.0.1:5760",
                           help="tcp:HOST:PORT, udp:HOST:PORT (default tcp:127.0.0.1:5760; port 0 picks a free one) "
                                "or serial:PATH[:BAUD] (a pseudo-terminal linked at PATH: USB without a baud, a UART "
                                "at BAUD)")
    add_fault_option(ardupilot, "ardupilot")
    inav = flavours.add_parser("inav", parents=[board], help="a simulated INAV flight controller (MSP): one compass, "
                                                             "calibrated and aligned in MSP_RAW_IMU (10 Hz)")
    inav.add_argument("--listen", default="tcp:127.0.0.1:5760",
                      help="tcp:HOST:PORT (default tcp:127.0.0.1:5760, as INAV's SITL; port 0 picks a free one) or "
                           "serial:PATH[:BAUD] (a pseudo-terminal linked at PATH)")
    add_fault_option(inav, "inav")
    coil = flavours.add_parser("coil", help="a 3-axis Helmholtz coil current source with a fluxgate DAQ at its "
                                            "centre (SCPI)")
    coil.add_argument("--listen", default="tcp:127.0.0.1:5026", help="the coil's address (default tcp:127.0.0.1:5026)")
    coil.add_argument("--fluxgate", default="tcp:127.0.0.1:5027", help="the fluxgate DAQ's address "
                                                                       "(default tcp:127.0.0.1:5027)")
    coil.add_argument("--coil-fault", choices=["output_off", "over_current", "scpi_error", "silent"])
    coil.add_argument("--seed", type=int, default=7, help="seed of the ambient field and the fluxgate's noise")
    gimbal = flavours.add_parser("gimbal", help="a motorised gimbal controller for slot stations (SCPI)")
    gimbal.add_argument("--listen", default="tcp:127.0.0.1:5030", help="its address (default tcp:127.0.0.1:5030)")
    table = flavours.add_parser("turntable", help="a turntable rig (SCPI stage controller) under a cradle, with a "
                                                  "simulated operator who tilts the cradle as its pendant asks")
    table.add_argument("--listen", default="tcp:127.0.0.1:5050", help="its address (default tcp:127.0.0.1:5050)")
    table.add_argument("--operator", default="follow", choices=["follow", "wrong", "never"],
                       help="follow: sets each tilt asked; wrong: first sets a wrong tilt and corrects it when the "
                            "pendant names it; never: never tilts (default follow)")
    table.add_argument("--reaction", type=NOT_NEGATIVE, default=0.5, metavar="S",
                       help="seconds the operator takes to react to the pendant (default 0.5)")
    table.add_argument("--table-fault", choices=["not_homed", "not_turning", "stalls", "lost_link"])
    load = flavours.add_parser("load", help="a programmable DC electronic load on its own (SCPI): to try a station's "
                                            "current_source wiring; for a sweep, run it with its board "
                                            "(magline sim px4|ardupilot --load tcp:HOST:PORT), whose current sensor "
                                            "its current must flow through")
    load.add_argument("--listen", default="tcp:127.0.0.1:5040", help="its address (default tcp:127.0.0.1:5040)")
    load.add_argument("--rating", type=POSITIVE, default=60.0, metavar="A", help="its largest current (default 60 A)")
    load.add_argument("--load-fault", choices=["no_sink"], help="the input reports on but nothing flows")
    sim.set_defaults(handler=run_sim)


@contextmanager
def _listening(what: str, address: str | None) -> Iterator[None]:
    """An address that cannot be listened on is named in the error, with what was to listen there: the
    station's simulators share defaults (INAV's and ArduPilot's are both tcp:127.0.0.1:5760)."""
    try:
        yield
    except OSError as exc:
        taken = " — another program (another simulator?) listens there: give this one another address" \
            if exc.errno == errno.EADDRINUSE else ""
        raise OSError(f"cannot listen on {address} ({what}): {exc.strerror or exc}{taken}") from exc


def add_fault_option(parser: argparse.ArgumentParser, board: str) -> None:
    """``--fault`` with the faults this board's simulator has, each with its value's form."""
    parser.add_argument("--fault", action="append", default=[], metavar="NAME[=VALUE]",
                        help=f"inject a fault (repeat for several): {fault_list(board)}")


def fault_list(board: str | None = None) -> str:
    """The faults :class:`~magline.sim.faults.SimFaults` knows for ``board`` (all for None), with what each
    value says: the help is made from the class, so a fault added there is listed here."""
    from magline.sim.faults import SimFaults

    def shown(f: Any) -> str:
        default = f.default_factory() if callable(f.default_factory) else f.default
        if isinstance(default, bool):
            return f.name
        if "form" in f.metadata:  # the value's own form, as the fault's comment in SimFaults says it
            return f"{f.name}={f.metadata['form']}"
        if isinstance(default, list):
            return f"{f.name}=A,B"
        return f"{f.name}=V"

    return ", ".join(shown(f) for f in SimFaults.for_board(board))


def default_workdir(flavour: str, listen: str) -> Path:
    """Where a board keeps its storage unless told: a folder of its own under the temporary folder, the
    same for the same simulator on the same address (a board keeps its parameters across restarts, as
    a real one does), a fresh one for a free port (port 0) — never the folder magline is started in."""
    if listen.rsplit(":", 1)[-1] == "0":
        return Path(tempfile.mkdtemp(prefix=f"magline-sim-{flavour}-"))
    folder = Path(tempfile.gettempdir()) / "magline-sim" / f"{flavour}-{re.sub(r'[^A-Za-z0-9]+', '_', listen)}"
    folder.mkdir(parents=True, exist_ok=True)
    return folder


_STOP_REQUESTED = threading.Event()  # set by SIGTERM; polled, never waited on inside a signal handler


def _terminate(signum: int, frame: object) -> None:
    # Only note it: raising out of a handler that interrupted Event.wait() could leave the event's lock
    # in a state its own Event.set() then blocks on (a simulator that once ignored SIGTERM for 10 s in
    # the suite); the serving loop polls the flag instead.  Event.set() here is safe: the main thread
    # never holds this event's lock (nothing waits on it).
    _STOP_REQUESTED.set()


def _serve(lines: list[str], wait: Callable[[], None], stop: Callable[[], None]) -> int:
    """Announce (first line: ``listening on …``), run until Ctrl-C or SIGTERM, then stop; exit 0.
    ``wait`` is the simulator's own blocking wait (kept for callers; the loop here polls instead)."""
    signal.signal(signal.SIGTERM, _terminate)  # before "listening on": a caller may stop us at once
    why = "stopped"
    try:
        for line in lines:
            print(line, flush=True)
        while not _STOP_REQUESTED.is_set():
            time.sleep(0.1)
        why = "stopped by SIGTERM"
    except KeyboardInterrupt:
        why = "stopped by Ctrl-C"
    finally:
        stop()
    print(f"{why}: the simulator has closed its socket", flush=True)
    return 0


def run_sim(args: argparse.Namespace) -> int:
    if args.flavour == "coil":
        return run_coil_sim(args)
    if args.flavour == "load":
        return run_load_sim(args)
    if args.flavour == "gimbal":
        return run_gimbal_sim(args)
    if args.flavour == "turntable":
        return run_turntable_sim(args)
    from magline.sim import SimFaults, create_sim
    from magline.sim.magnetometers import MOTIONS

    motions = tuple(m.strip() for m in (args.motion or "").split(",") if m.strip()) or None
    unknown = [m for m in motions or () if m not in MOTIONS]
    try:
        if unknown:
            raise ValueError(f"unknown motion {unknown[0]!r}; choose from {', '.join(MOTIONS)}")
        if args.flavour == "inav" and args.mags != 1:
            raise ValueError("INAV uses one compass: --mags 1")
        workdir = args.workdir or default_workdir(args.flavour, args.listen)
        options: dict[str, Any] = {"workdir": workdir, "mag_count": args.mags, "boot_time_s": args.boot_time,
                                   "motions": motions, "speed": args.speed, "field_ut": args.field_ut,
                                   "inclination_deg": args.inclination_deg, "seed": args.seed,
                                   "faults": SimFaults.parse(args.fault, args.flavour), "mag_rate_hz": args.mag_rate,
                                   "motion_source": args.gimbal or args.turntable,
                                   "usb_aliases": tuple(args.usb_alias),
                                   "usb_powered": args.usb_powered}
        if args.flavour == "px4":
            options.update(firmware=args.firmware, shell=not args.no_shell, preset_ids=args.preset_ids,
                           untagged=args.untagged)
        with _listening("the flight controller", args.listen):
            sim = create_sim(args.flavour, args.listen, **options)
        for mag in sim.magnetometers:
            mag.truth.noise_ut = args.noise_ut
        with _listening("the flight controller", args.listen):
            sim.start()
        supply = None
        if args.supply:
            from magline.sim.supply import SupplySim
            with _listening("the bench supply", args.supply):
                supply = SupplySim(args.supply, board=sim, fault=args.supply_fault).start()
            sim.power_off()  # the supply's output starts off
        load = None
        if args.load:
            from magline.sim.load import LoadSim
            with _listening("the electronic load", args.load):
                load = LoadSim(args.load, board=sim, fault=args.load_fault, rating_a=args.load_rating).start()
        hub = None
        if args.usb_hub:
            from magline.sim.usb_hub import UsbHubSim
            with _listening("the USB hub", args.usb_hub):
                hub = UsbHubSim(args.usb_hub, boards={args.hub_port: sim}).start()
    except (ValueError, OSError) as exc:
        print(f"magline sim: {exc}", file=sys.stderr)
        return 2
    lines = [f"listening on {sim.address}"]
    if supply is not None:
        lines.append(f"supply listening on {supply.address} (VISA {supply.visa_resource}), output off")
    if load is not None:
        lines.append(f"electronic load listening on {load.address} (VISA {load.visa_resource}), input off, "
                     f"rated {load.rating_a:g} A")
    if hub is not None:
        lines.append(f"usb hub {hub.location} listening on {hub.address}, the board on port {args.hub_port} "
                     f"(uhubctl: MAGLINE_SIM_USB_HUB={hub.address} python -m magline.sim.uhubctl)")
    lines.append(f"{args.flavour} simulator, storage {sim.storage_path}, boot time {sim.boot_time_s:g} s")
    for mag in sim.magnetometers:
        h = ", ".join(f"{v:.2f}" for v in mag.hard_iron_ut)
        s = "; ".join(", ".join(f"{v:.4f}" for v in row) for row in mag.soft_iron)
        per_amp = ", ".join(f"{v:.3f}" for v in mag.interference_ut_per_a)
        lines.append(f"  magnetometer {mag.device_id}: hard iron [{h}] µT, soft iron [{s}], current interference "
                     f"[{per_amp}] µT/A")

    def stop() -> None:
        sim.stop()
        for instrument in (supply, hub, load):
            if instrument is not None:
                instrument.stop()

    return _serve(lines, sim.wait_stopped, stop)


def run_coil_sim(args: argparse.Namespace) -> int:
    from magline.sim.coil import CoilSim
    from magline.sim.fluxgate import FluxgateSim

    try:
        with _listening("the coil", args.listen):
            coil = CoilSim(args.listen, fault=args.coil_fault, seed=args.seed).start()
        with _listening("the fluxgate", args.fluxgate):
            fluxgate = FluxgateSim(args.fluxgate, coil.true_field_ut, seed=args.seed).start()
    except (ValueError, OSError) as exc:
        print(f"magline sim: {exc}", file=sys.stderr)
        return 2
    lines = [f"listening on {coil.address}",
             f"coil current source (VISA {coil.visa_resource}); fluxgate DAQ at the centre on {fluxgate.address} "
             f"(VISA {fluxgate.visa_resource}); ambient field {coil.ambient.tolist()} µT"]

    def stop() -> None:
        coil.stop()
        fluxgate.stop()

    return _serve(lines, coil.wait_stopped, stop)


def run_gimbal_sim(args: argparse.Namespace) -> int:
    from magline.sim.gimbal import GimbalSim

    try:
        with _listening("the gimbal", args.listen):
            gimbal = GimbalSim(args.listen).start()
    except (ValueError, OSError) as exc:
        print(f"magline sim: {exc}", file=sys.stderr)
        return 2
    lines = [f"listening on {gimbal.address}",
             f"gimbal controller (VISA {gimbal.visa_resource}); mount simulated boards on it with "
             f"magline sim px4|ardupilot --gimbal {gimbal.address}"]

    return _serve(lines, gimbal.wait_stopped, gimbal.stop)


def run_turntable_sim(args: argparse.Namespace) -> int:
    from magline.sim.turntable import TurntableSim

    try:
        with _listening("the turntable", args.listen):
            table = TurntableSim(args.listen, operator=args.operator, reaction_s=args.reaction,
                                 fault=args.table_fault).start()
    except (ValueError, OSError) as exc:
        print(f"magline sim: {exc}", file=sys.stderr)
        return 2
    lines = [f"listening on {table.address}",
             f"turntable controller (VISA {table.visa_resource}), not homed yet; a simulated operator who "
             f"{'sets each tilt its pendant asks' if args.operator == 'follow' else args.operator + ' tilts'}; "
             f"put simulated boards in its cradle with magline sim px4|ardupilot|inav --turntable {table.address}"]
    return _serve(lines, table.wait_stopped, table.stop)


def run_load_sim(args: argparse.Namespace) -> int:
    from magline.sim.load import LoadSim

    try:
        with _listening("the electronic load", args.listen):
            load = LoadSim(args.listen, fault=args.load_fault, rating_a=args.rating).start()
    except (ValueError, OSError) as exc:
        print(f"magline sim: {exc}", file=sys.stderr)
        return 2
    lines = [f"listening on {load.address}",
             f"electronic load (VISA {load.visa_resource}), input off, rated {load.rating_a:g} A, in no board's "
             "power path: for a sweep run it with its board (magline sim px4|ardupilot --load ADDRESS)"]
    return _serve(lines, load.wait_stopped, load.stop)
