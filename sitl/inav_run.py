"""A good INAV unit, and one whose compass is turned, through the real ``magline run`` on INAV's own SITL.

The firmware is fed by :mod:`magline.sitl.inav_xplane` (a compass of known distortion, tumbled); the
station is the shipped ``stations/inav-sim.yaml`` pointed at the SITL (its fake compass reads 1024 counts
per gauss).  After the run the SITL is killed (a hard power cut) and started again on the same storage,
and its settings are read over MSP and held to the truth.  INAV's SITL listens on every interface, so the
whole run happens in a private network namespace (``unshare -n``, entered by re-executing itself).

    python -m magline.sitl.inav_run --sitl PATH/TO/SITL.elf [--workdir DIR] [--seed 1] [--turned 2] [--json OUT]

Prints one line per check (figure against tolerance) and exits 0 when every one holds.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np
import yaml

from magline.core.links.msp import Msp, MspClient, parse_setting_info
from magline.sitl.checks import (
    MATRIX_GOAL,
    OFFSET_GOAL_MG,
    Check,
    fit_sigmas,
    in_private_network,
    run_station,
    runner_parser,
    station_figures,
    summarise,
    true_to_sigma,
    write_station,
)
from magline.sitl.inav_xplane import COUNTS_PER_GAUSS, InavTruth, XPlanePeer

MSP_ADDRESS = "tcp:127.0.0.1:5760"  # SITL's UART1


def _msp(timeout_s: float = 20.0) -> MspClient:
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            client = MspClient.connect(MSP_ADDRESS, connect_timeout_s=1.0)
            client.request(Msp.API_VERSION)
            return client
        except Exception:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.3)


def _settings(names: list[str]) -> dict[str, int]:
    client = _msp()
    try:
        return {n: int(parse_setting_info(n, client.request(Msp.COMMON_SETTING_INFO, n.encode() + b"\0")).value)
                for n in names}
    finally:
        client.close()


def _station(workdir: Path, truth: InavTruth) -> Path:
    shipped = yaml.safe_load((Path(__file__).resolve().parent.parent / "stations" / "inav-sim.yaml").read_text())
    options = {**next(iter(shipped["products"].values()))["options"], "counts_per_gauss": COUNTS_PER_GAUSS}
    return write_station("inav-sim.yaml", workdir, truth.field_ut, truth.inclination_deg,
                         {"connection": MSP_ADDRESS, "options": options})


class Sitl:
    """The SITL process, started and killed as a power supply would."""

    def __init__(self, binary: Path, workdir: Path) -> None:
        self.binary, self.workdir, self.proc = binary, workdir, None
        self.log = open(workdir / "sitl.log", "ab")  # noqa: SIM115 — kept open across power cycles

    def start(self) -> None:
        # restore_signals=False: the SITL inherits Python's ignored SIGPIPE (and keeps it across its own
        # re-exec at a reboot).  Its TCP "serial port" sends without MSG_NOSIGNAL (drivers/serial_tcp.c), so
        # a late reply to a client that timed out and closed would kill it (exit status −13, seen) where a
        # board on USB carries on: the run is of the firmware, not of its socket emulation.
        self.proc = subprocess.Popen([str(self.binary), "--sim=xp", "--simip=127.0.0.1", "--simport=49000"],
                                     cwd=self.workdir, stdout=self.log, stderr=subprocess.STDOUT,
                                     restore_signals=False)
        _msp().close()

    def cut(self) -> None:
        if self.proc is not None:
            died = self.proc.poll()
            if died is not None:  # it ended before the cut: say how, beside its own output
                self.log.write(f"[magline] the SITL had ended by itself: exit status {died}\n".encode())
                self.log.flush()
            self.proc.kill()
            self.proc.wait()


def one_unit(binary: Path, workdir: Path, seed: int, alignment: int | None) -> tuple[dict, list[Check]]:
    """Run one unit; the compass sits at ``alignment`` (None: where INAV's default expects it)."""
    workdir.mkdir(parents=True, exist_ok=True)
    (workdir / "eeprom.bin").unlink(missing_ok=True)
    truth = InavTruth.drawn(seed, speed=0.3, **({} if alignment is None else {"alignment": alignment}))
    (workdir / "truth.json").write_text(json.dumps(asdict(truth), indent=2) + "\n")
    peer = XPlanePeer(truth, seed=seed)
    threading.Thread(target=peer.serve, daemon=True).start()
    sitl = Sitl(binary, workdir)
    try:
        sitl.start()
        station = _station(workdir, truth)
        record, cycle_s = run_station(station, f"SITL-INAV-{seed}", workdir)
        sitl.cut()  # the hard power cut: what was saved is what the unit keeps
        sitl.start()
        kept = _settings(list(truth.expected))
    finally:
        sitl.cut()
        sitl.log.close()
        peer.stop()
    return record, _judge(truth, record, kept, cycle_s, turned=alignment is not None)


def _judge(truth: InavTruth, record: dict, kept: dict[str, int], cycle_s: float, turned: bool) -> list[Check]:
    verdict, cause = record.get("verdict"), record.get("cause") or ""
    if turned:
        fix = f"align_mag = {truth.alignment}"
        return [Check("turned compass FAILs naming its fix", f"{verdict}: {cause[:60]}", f"FAIL, '{fix}'",
                      verdict == "fail" and fix in cause),
                Check("nothing written to a failed unit", str(kept["align_mag"]), "align_mag unchanged (8)",
                      kept["align_mag"] == 8 and not (record.get("params") or {}).get("written"))]
    checks = [Check("good unit PASSes", f"{verdict} {cause[:40]}", "pass", verdict == "pass")]
    hard_sigma_ut, soft_sigma = fit_sigmas(record)
    mg_per_count = 1000.0 / COUNTS_PER_GAUSS
    zeros = [f"magzero_{a}" for a in "xyz"]
    checks.append(true_to_sigma("magzero", np.array([kept[n] - truth.expected[n] for n in zeros]) * mg_per_count,
                                hard_sigma_ut * 10.0, "mG", OFFSET_GOAL_MG, quantum=mg_per_count))
    # maggain = 1024·B / S_ii counts: a relative σ of S_ii is the gain's own; INAV keeps whole counts
    gains = [f"maggain_{a}" for a in "xyz"]
    expected = np.array([truth.expected[n] for n in gains], float)
    relative = np.array([kept[n] for n in gains]) / expected - 1.0
    checks.append(true_to_sigma("maggain (relative)", relative, np.diag(soft_sigma) / np.asarray(truth.soft_iron_diag),
                                "", MATRIX_GOAL, quantum=float(np.max(1.0 / expected))))
    return [*checks, *station_figures(record, cycle_s)]


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = runner_parser("magline.sitl.inav_run", __doc__, "--sitl", "INAV's SITL.elf, built from INAV's own tree")
    parser.add_argument("--turned", type=int, default=2, help="the align_mag value the turned compass sits at")
    args = parser.parse_args(argv)
    if not args.sitl.is_file():
        print(f"INAV SITL not found at {args.sitl}: build INAV's SITL target and give its SITL.elf", file=sys.stderr)
        return 2
    refused = in_private_network("magline.sitl.inav_run", argv)  # INAV's SITL listens on every interface
    if refused:
        print(refused, file=sys.stderr)
        return 2
    workdir = args.workdir or Path(tempfile.mkdtemp(prefix="magline-sitl-inav-"))
    return summarise(f"INAV SITL {args.sitl}", workdir,
                     {"good": lambda folder: one_unit(args.sitl, folder, args.seed, None),
                      "turned": lambda folder: one_unit(args.sitl, folder, args.seed, args.turned)},
                     args.json, args.unit)

if __name__ == "__main__":
    sys.exit(main())
