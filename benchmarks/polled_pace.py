"""How thin a station's polls of an INAV board may get before a good unit cannot be judged (printed, never
asserted): a simulated INAV unit (MSP on loopback, its compass at 100 Hz) through the real station at each
tumble pace and poll rate asked, its verdict, readings and the rate achieved.  Why: over MSP the station reads
the board as often as its loop runs, so a loaded machine thins the polls; the tests' pace
(``magline.testing.sims.POLLED_SPEED``) must leave a margin below the 50 Hz the shipped station asks.

    python benchmarks/polled_pace.py [--speeds 5,2,1] [--rates 50,20,12,6]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))

from simstation import FAST_SENSOR_HZ, run_unit, write_station  # noqa: E402

from magline.sim import create_sim  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--speeds", default="5,2,1")
    parser.add_argument("--rates", default="50,20,12,6")
    args = parser.parse_args()
    print(f"{'pace':>5} {'polls Hz':>8} {'verdict':>8} {'readings':>8} {'achieved Hz':>11} {'wall s':>7}  cause")
    for speed in (float(s) for s in args.speeds.split(",")):
        for rate in (float(r) for r in args.rates.split(",")):
            folder, started = Path(tempfile.mkdtemp()), time.monotonic()
            with create_sim("inav", "tcp:127.0.0.1:0", workdir=folder / "fc", seed=11, boot_time_s=0.3, speed=speed,
                            mag_rate_hz=FAST_SENSOR_HZ) as sim:
                options = {"connect_timeout_s": 4.0, "boot_timeout_s": 8.0}
                asked = {"acquisition": {"rate_hz": rate}}
                station = write_station("inav-sim.yaml", folder, sim.address, options, asked)
                record = run_unit(station)
            attempt = record.attempts[-1]
            print(f"{speed:5g} {rate:8g} {record.verdict.value:>8} {attempt.samples:8d} "
                  f"{attempt.sensor_rate_hz or 0:11.1f} {time.monotonic() - started:7.1f}  {(record.cause or '')[:70]}",
                  flush=True)


if __name__ == "__main__":
    main()
