"""Units on serial ports (issue 48): what a serial line costs a unit, and what a UART carries.

Printed, for a simulated PX4 and ArduPilot board (one compass, the station's 200 readings a second,
the simulators' 0.3 s boot):
1. one unit's cycle time and acquisition over TCP/UDP, over USB (a CDC ACM port: the baud ignored), and
   over a UART at 115200 and 921600 baud — the whole unit, its power cycle (a MAVLink reboot, the port
   re-enumerating) included;
2. at 115200 baud, for stream rates from 25 to 400 messages a second: the IMU messages a second the
   line delivered to the station (3 s of streaming through the backend's own link), what the
   firmware's transmit buffer dropped, and whether the station refuses the rate before acquiring.

    python benchmarks/serial_link.py [--units 3]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))

from magline.core.faults import StationFault  # noqa: E402
from magline.core.links.serial_port import mavlink2_frame_bytes  # noqa: E402
from magline.core.record import Outcome  # noqa: E402
from magline.sim import create_sim  # noqa: E402
from magline.testing.stations import deep_update, run_unit  # noqa: E402

EXAMPLES = {"px4": ("px4-sim.yaml", "PX4-X500-100", {"connect_timeout_s": 5.0, "boot_timeout_s": 10.0}),
            "ardupilot": ("ardupilot-sim.yaml", "AP-QUAD-200",
                          {"connect_timeout_s": 5.0, "boot_timeout_s": 10.0, "prearm_wait_s": 0.3})}
ACQUISITION = {"samples": 400, "rate_hz": 200.0, "retry_delay_s": 0.0, "timeout_s": 30.0}
SENSOR_HZ = 100.0


def station_file(folder: Path, flavour: str, connection: str) -> Path:
    example, part, options = EXAMPLES[flavour]
    cfg = yaml.safe_load((REPO / "stations" / example).read_text(encoding="utf-8"))
    cfg = deep_update(cfg, {"products": {part: {"connection": connection, "options": options}},
                            "acquisition": ACQUISITION, "results": {"path": str(folder / "results.sqlite")}})
    path = folder / "station.yaml"
    path.write_text(yaml.safe_dump(cfg, sort_keys=False), encoding="utf-8")
    return path


def one_unit(flavour: str, link: str, folder: Path, seed: int) -> tuple[float, float, float, int]:
    """(cycle s, acquisition readings a second, tumble s, frames the board dropped) of one unit."""
    serial = folder / "dev" / "serial" / "by-path" / "pci-0000:00:14.0-usb-0:3:1.0-port0"
    listen, connection = {
        "network": ("udp:127.0.0.1:0", None) if flavour == "px4" else ("tcp:127.0.0.1:0", None),
        "usb": (f"serial:{serial}", f"serial:{serial}:115200"),
        "uart 115200": (f"serial:{serial}:115200", f"serial:{serial}:115200"),
        "uart 921600": (f"serial:{serial}:921600", f"serial:{serial}:921600"),
    }[link]
    with create_sim(flavour, listen, workdir=folder / "fc", seed=seed, boot_time_s=0.3, speed=5.0,
                    mag_rate_hz=SENSOR_HZ) as board:
        if connection is None:
            _, host, port = board.address.split(":")
            connection = f"udpout://{host}:{port}" if flavour == "px4" else board.address
        started = time.monotonic()
        record = run_unit(station_file(folder, flavour, connection), serial=f"BENCH-{seed}")
        cycle = time.monotonic() - started
        dropped = getattr(board.link, "tx_dropped", 0)
    if record.verdict is not Outcome.PASS:
        raise SystemExit(f"{flavour} over {link}: {record.verdict} — {record.cause}")
    attempt = record.attempts[-1]
    tumble = attempt.tumble_s or 0.0
    return cycle, (attempt.samples / tumble if tumble else 0.0), tumble, dropped


def line_carries(flavour: str, rate_hz: float, folder: Path) -> tuple[float, int, str]:
    """(IMU messages a second received, frames the board dropped, the station's refusal or "") for 3 s of
    the backend's IMU stream at ``rate_hz`` over a UART at 115200."""
    serial = folder / f"uart-{flavour}-{rate_hz:g}"
    with create_sim(flavour, f"serial:{serial}:115200", workdir=folder / "fc", seed=3, boot_time_s=0.3,
                    mag_rate_hz=SENSOR_HZ) as board:
        if flavour == "px4":
            from magline.plugins.px4.link import Px4Link

            link = Px4Link(f"serial:{serial}:115200", connect_timeout_s=5.0)
            link.open()
            try:
                refusal = _refusal(link.port, {"SCALED_IMU": (mavlink2_frame_bytes(26), rate_hz)})
                inbox, handles = link.subscribe_all(["SCALED_IMU"])
                link.require_accepted(511, "stream", 26, 1e6 / rate_hz)
                time.sleep(0.5)
                while not inbox.empty():
                    inbox.get_nowait()
                started, got = time.monotonic(), 0
                while time.monotonic() - started < 3.0:
                    time.sleep(0.05)
                    while not inbox.empty():
                        inbox.get_nowait()
                        got += 1
                for handle in handles:
                    link.unsubscribe(handle)
            finally:
                link.close()
        else:
            from magline.plugins.ardupilot.link import ArduPilotLink

            link = ArduPilotLink(f"serial:{serial}:115200")
            link.open(5.0)
            try:
                refusal = _refusal(link.port, {"RAW_IMU": (mavlink2_frame_bytes(27), rate_hz)})
                link.set_message_interval(27, rate_hz)
                link.recv("RAW_IMU", 0.5)
                time.sleep(0.5)
                link.drain()
                started, got = time.monotonic(), 0
                while time.monotonic() - started < 3.0:
                    if link.recv("RAW_IMU", 0.2) is not None:
                        got += 1
            finally:
                link.close()
        dropped = board.link.tx_dropped
    return got / 3.0, dropped, refusal


def _refusal(port, streams) -> str:
    """The station's answer before acquiring: "" when it accepts the rate, else the figures."""
    try:
        port.require_capacity(streams)
    except StationFault:
        need = sum(size * rate for size, rate in streams.values())
        return f"refused: needs {need:,.0f} of {port.address.baud / 10:,.0f} bytes/s (frames at their longest)"
    return ""


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--units", type=int, default=3, help="units per flavour and link (default 3)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        print(f"1. one unit, {args.units} per row (median; 200 readings/s asked, sensor {SENSOR_HZ:g} Hz, "
              "boot 0.3 s)")
        print(f"   {'board':10} {'link':12} {'cycle s':>8} {'readings/s':>11} {'tumble s':>9} {'dropped':>8}")
        for flavour in EXAMPLES:
            for link in ("network", "usb", "uart 115200", "uart 921600"):
                rows = [one_unit(flavour, link, folder / f"{flavour}-{link}-{i}".replace(" ", "-"), seed=10 + i)
                        for i in range(args.units)]
                cycle, rate, tumble, dropped = (statistics.median(r[k] for r in rows) for k in range(4))
                print(f"   {flavour:10} {link:12} {cycle:8.2f} {rate:11.1f} {tumble:9.2f} {dropped:8.0f}")
        print("\n2. what a UART at 115200 baud carries of the IMU stream (3 s each)")
        print(f"   {'board':10} {'asked/s':>8} {'received/s':>11} {'dropped':>8}  station")
        for flavour in EXAMPLES:
            for rate in (25.0, 50.0, 100.0, 200.0, 250.0, 300.0, 400.0):
                got, dropped, refusal = line_carries(flavour, rate, folder)
                print(f"   {flavour:10} {rate:8.0f} {got:11.1f} {dropped:8d}  {refusal or 'accepted'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
