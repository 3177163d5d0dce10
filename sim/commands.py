"""``magline sim px4|ardupilot|coil|gimbal``: run a simulator on a real socket until Ctrl-C / SIGTERM.

The first line printed names the address it listens on, so a script (or a person in another
terminal) knows where to point the station.  The simulator itself is imported only when the
command runs.  The command comes through its own ``sim`` entry point in the ``magline`` group
(``magline_add_commands``), as any plugin's command does: the core CLI knows nothing of simulators,
and the mock DUT plugin (an in-process unit) has nothing to do with them.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

from magline.core.plugins import hookimpl


@hookimpl
def magline_add_commands(subparsers: Any) -> None:
    add_sim_command(subparsers)


def add_sim_command(subparsers: argparse._SubParsersAction) -> None:
    sim = subparsers.add_parser("sim", help="run a simulated flight controller (MAVLink) or Helmholtz coil (SCPI)")
    sim.add_argument("flavour", choices=["px4", "ardupilot", "coil", "gimbal"],
                     help="coil: a 3-axis Helmholtz coil current source (default tcp:127.0.0.1:5026) with a "
                          "fluxgate DAQ at its centre (--fluxgate, default tcp:127.0.0.1:5027); gimbal: a "
                          "motorised gimbal controller (default tcp:127.0.0.1:5030) for slot stations")
    sim.add_argument("--listen", help="udp:HOST:PORT or tcp:HOST:PORT (default: px4 udp:127.0.0.1:14550, "
                                      "ardupilot tcp:127.0.0.1:5760; port 0 picks a free one)")
    sim.add_argument("--workdir", default=".", help="where the parameter storage file lives (default: .)")
    sim.add_argument("--mags", type=int, default=1, choices=[1, 2, 3], help="number of magnetometers")
    sim.add_argument("--boot-time", type=float, default=2.0, help="seconds silent after a reboot (default 2)")
    sim.add_argument("--motion",
                     help="comma list, one per acquisition (tumble, single_axis, gimbal, still, shared); last "
                          "repeats (default: tumble, or shared with --gimbal)")
    sim.add_argument("--gimbal", metavar="tcp:HOST:PORT",
                     help="the board is mounted on this gimbal simulator and moves with it (motion 'shared')")
    sim.add_argument("--speed", type=float, default=1.0, help="tumble speed factor")
    sim.add_argument("--field-ut", type=float, default=48.0, help="local field magnitude (µT)")
    sim.add_argument("--inclination-deg", type=float, default=62.0)
    sim.add_argument("--noise-ut", type=float, default=0.3)
    sim.add_argument("--mag-rate", type=float, metavar="HZ",
                     help="how often the sensors publish a new reading (default: ardupilot 10 Hz, px4 per driver); "
                          "a faster stream repeats readings, as real vehicles do")
    sim.add_argument("--seed", type=int, default=7, help="seed of the sensors' distortion and noise")
    sim.add_argument("--firmware", default="1.15.0", help="px4 only: firmware version (ODIAG from 1.12)")
    sim.add_argument("--untagged", action="store_true",
                     help="px4 only: report version 0.0.0, as a build from an untagged tree (SITL) does")
    sim.add_argument("--no-shell", action="store_true",
                     help="px4 only: the MAVLink shell answers nothing, as on POSIX builds (SITL)")
    sim.add_argument("--preset-ids", action="store_true",
                     help="px4 only: CAL_MAGn_ID preset to the detected sensors, as POSIX startup scripts do")
    sim.add_argument("--fault", action="append", default=[], metavar="NAME[=VALUE]",
                     help="inject a fault, e.g. drop_percent=5, ignore_param_set=CAL_MAG0_XOFF, "
                          "no_persist=NAME, reboot_fails, link_loss_after_s=3, mag_missing_after_reboot=ID, "
                          "swap_mags_after_reboot")
    sim.add_argument("--supply", metavar="tcp:HOST:PORT",
                     help="also run a simulated SCPI bench supply that powers this board (it starts off)")
    sim.add_argument("--supply-fault", choices=["dead_board", "short", "output_error"])
    sim.add_argument("--fluxgate", default="tcp:127.0.0.1:5027", help="coil only: the fluxgate DAQ's address")
    sim.add_argument("--coil-fault", choices=["output_off", "over_current", "scpi_error", "silent"])
    sim.set_defaults(handler=run_sim)


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
    try:
        for line in lines:
            print(line, flush=True)
        while not _STOP_REQUESTED.is_set():
            time.sleep(0.1)
    except KeyboardInterrupt:
        pass
    finally:
        stop()
    return 0


def run_sim(args: argparse.Namespace) -> int:
    if args.flavour == "coil":
        return run_coil_sim(args)
    if args.flavour == "gimbal":
        return run_gimbal_sim(args)
    from magline.sim import SimFaults, create_sim
    from magline.sim.magnetometers import MOTIONS

    motions = tuple(m.strip() for m in (args.motion or "").split(",") if m.strip()) or None
    unknown = [m for m in motions or () if m not in MOTIONS]
    try:
        if unknown:
            raise ValueError(f"unknown motion {unknown[0]!r}; choose from {', '.join(MOTIONS)}")
        options: dict[str, Any] = {"workdir": args.workdir, "mag_count": args.mags, "boot_time_s": args.boot_time,
                                   "motions": motions, "speed": args.speed, "field_ut": args.field_ut,
                                   "inclination_deg": args.inclination_deg, "seed": args.seed,
                                   "faults": SimFaults.parse(args.fault), "mag_rate_hz": args.mag_rate,
                                   "motion_source": args.gimbal}
        if args.flavour == "px4":
            options.update(firmware=args.firmware, shell=not args.no_shell, preset_ids=args.preset_ids,
                           untagged=args.untagged)
        sim = create_sim(args.flavour, args.listen, **options)
        for mag in sim.magnetometers:
            mag.truth.noise_ut = args.noise_ut
        sim.start()
        supply = None
        if args.supply:
            from magline.sim.supply import SupplySim
            supply = SupplySim(args.supply, board=sim, fault=args.supply_fault).start()
            sim.power_off()  # the supply's output starts off
    except (ValueError, OSError) as exc:
        print(f"magline sim: {exc}", file=sys.stderr)
        return 2
    lines = [f"listening on {sim.address}"]
    if supply is not None:
        lines.append(f"supply listening on {supply.address} (VISA {supply.visa_resource}), output off")
    lines.append(f"{args.flavour} simulator, storage {sim.storage_path}, boot time {sim.boot_time_s:g} s")
    for mag in sim.magnetometers:
        h = ", ".join(f"{v:.2f}" for v in mag.hard_iron_ut)
        s = "; ".join(", ".join(f"{v:.4f}" for v in row) for row in mag.soft_iron)
        lines.append(f"  magnetometer {mag.device_id}: hard iron [{h}] µT, soft iron [{s}]")

    def stop() -> None:
        sim.stop()
        if supply is not None:
            supply.stop()

    return _serve(lines, sim.wait_stopped, stop)


def run_coil_sim(args: argparse.Namespace) -> int:
    from magline.sim.coil import CoilSim
    from magline.sim.fluxgate import FluxgateSim

    try:
        coil = CoilSim(args.listen or "tcp:127.0.0.1:5026", fault=args.coil_fault, seed=args.seed).start()
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
        gimbal = GimbalSim(args.listen or "tcp:127.0.0.1:5030").start()
    except (ValueError, OSError) as exc:
        print(f"magline sim: {exc}", file=sys.stderr)
        return 2
    lines = [f"listening on {gimbal.address}",
             f"gimbal controller (VISA {gimbal.visa_resource}); mount simulated boards on it with "
             f"magline sim px4|ardupilot --gimbal {gimbal.address}"]

    return _serve(lines, gimbal.wait_stopped, gimbal.stop)
