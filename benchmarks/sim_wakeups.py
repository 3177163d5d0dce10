"""How often a simulated board's loop wakes, and the CPU it costs, idle and streaming.

A suite worker runs several simulated boards beside the station on one interpreter lock, so a board that
wakes when it has nothing to do, or spends long on each message, takes time from everything else.  This
prints, per board, the loop's wake-ups a second and its thread's CPU share over a few seconds: idle (no
station), and streaming its compass at 100 Hz to a station that asks for it (ArduPilot also three compasses at
100 Hz each); then the time one streamed message takes to compute (its reading and the body's gravity, median
of 2,000).

    python benchmarks/sim_wakeups.py [--seconds 5]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import threading
import time
from pathlib import Path

from pymavlink import mavutil

from magline.sim import create_sim


def _thread_cpu_s(thread: threading.Thread) -> float:
    """The CPU seconds the thread has used (Linux: its /proc task entry)."""
    import os

    fields = Path(f"/proc/self/task/{thread.native_id}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _measure(board, seconds: float) -> tuple[float, float]:
    steps = [0]
    step = board._step

    def counted() -> None:
        steps[0] += 1
        step()

    board._step = counted
    time.sleep(0.5)
    steps[0], cpu0, t0 = 0, _thread_cpu_s(board._thread), time.monotonic()
    time.sleep(seconds)
    elapsed = time.monotonic() - t0
    return steps[0] / elapsed, (_thread_cpu_s(board._thread) - cpu0) / elapsed


def _read_until(station, done: threading.Event) -> None:
    while not done.is_set():
        station.recv_match(blocking=True, timeout=0.1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=5.0)
    args = parser.parse_args()
    workdir = Path(tempfile.mkdtemp())
    print(f"{'board':<10} {'state':<22} {'wake-ups/s':>10} {'CPU share':>10}")
    # each board idle, then streaming one compass at 100 Hz; ArduPilot then three compasses at 100 Hz, as a
    # three-compass unit's acquisition asks (RAW_IMU, SCALED_IMU2, SCALED_IMU3)
    cases = (("px4", ("HIGHRES_IMU",)), ("ardupilot", ("RAW_IMU",)),
             ("ardupilot", ("RAW_IMU", "SCALED_IMU2", "SCALED_IMU3")))
    for case, (flavour, streams) in enumerate(cases):
        with create_sim(flavour, "tcp:127.0.0.1:0", workdir=workdir / f"{flavour}-{case}", seed=1, boot_time_s=0.2,
                        mag_rate_hz=100.0, mag_count=len(streams)).start() as board:
            if len(streams) == 1:
                wakes, cpu = _measure(board, args.seconds)
                print(f"{flavour:<10} {'idle':<22} {wakes:10.0f} {cpu:10.3f}")
            station = mavutil.mavlink_connection(board.address, source_system=255)
            station.wait_heartbeat(timeout=5)
            for stream in streams:
                msg_id = getattr(mavutil.mavlink, f"MAVLINK_MSG_ID_{stream}")
                station.mav.command_long_send(1, 1, mavutil.mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, msg_id,
                                              10_000, 0, 0, 0, 0, 0)
            done = threading.Event()

            reader = threading.Thread(target=_read_until, args=(station, done), daemon=True)
            reader.start()
            wakes, cpu = _measure(board, args.seconds)
            state = "streaming" if len(streams) == 1 else f"streaming {len(streams)} compasses"
            print(f"{flavour:<10} {state:<22} {wakes:10.0f} {cpu:10.3f}")
            done.set()
            reader.join()
            station.close()
    print(f"{'board':<10} {'message':<12} {'µs each':>8}")
    for flavour, stream in (("px4", "HIGHRES_IMU"), ("ardupilot", "RAW_IMU")):
        with create_sim(flavour, "tcp:127.0.0.1:0", workdir=workdir / f"{flavour}-msg", seed=1, boot_time_s=0.2,
                        mag_rate_hz=100.0).start() as board:
            time.sleep(0.5)
            msg_id = getattr(mavutil.mavlink, f"MAVLINK_MSG_ID_{stream}")
            took = []
            for _ in range(2000):
                board._held.clear()  # a new reading each time, as at the sensor's own rate
                started = time.perf_counter()
                with board.lock:
                    board.stream_message(msg_id, time.monotonic())
                took.append(time.perf_counter() - started)
            print(f"{flavour:<10} {stream:<12} {statistics.median(took) * 1e6:8.0f}")


if __name__ == "__main__":
    main()
