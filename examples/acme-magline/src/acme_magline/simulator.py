"""A simulated ACME board on a TCP port: known-truth sensor (magline.testing), tumbled for ever,
RAM parameters saved to a JSON "flash" only on SAVE, a reboot that drops the link.

    python -m acme_magline.simulator [--port 7000] [--flash acme-flash.json]
"""

from __future__ import annotations

import argparse
import json
import socket
import threading
import time
from pathlib import Path

import numpy as np
from magline.testing import SensorTruth, earth_field_ned, gravity_body, motion_directions

from acme_magline.protocol import MATRIX, PARAMS, UT_PER_MG

SENSOR_HZ = 100.0


class AcmeSim:
    def __init__(self, flash: Path, port: int = 0, field_ut: float = 48.0, boot_s: float = 0.3, seed: int = 5,
                 board_temp_c: float = 41.5) -> None:
        self.flash = Path(flash)
        self.board_temp_c = board_temp_c
        self.field_ut = field_ut
        self.boot_s = boot_s
        self.rng = np.random.default_rng(seed)
        self.truth = SensorTruth(hard_iron_ut=np.array([42.0, -17.0, 25.0]),
                                 soft_iron=np.array([[1.05, 0.02, 0.0], [0.02, 0.96, -0.01], [0.0, -0.01, 1.0]]),
                                 noise_ut=0.2)
        field = earth_field_ned(field_ut, 62.0)
        # the operator tumbles the board through every orientation every 4 s, for ever
        self.directions = motion_directions("hand_tumble", int(4 * SENSOR_HZ), self.rng, field)
        self.gravity_mg = gravity_body(self.directions, field) / 9.80665 * 1000.0  # its accelerometer, milli-g
        self.server = socket.create_server(("127.0.0.1", port))
        self.port = self.server.getsockname()[1]
        self.lock = threading.Lock()
        self.ram: dict[str, float] = {}
        self.booted_at = 0.0
        self.up_at = 0.0
        self._stop = threading.Event()
        self._boot()

    @property
    def connection(self) -> str:
        return f"tcp:127.0.0.1:{self.port}"

    def _boot(self) -> None:
        stored = json.loads(self.flash.read_text()) if self.flash.exists() else {}
        self.ram = {**PARAMS, **stored}
        self.booted_at = time.monotonic()
        self.up_at = self.booted_at + self.boot_s

    def start(self) -> AcmeSim:
        threading.Thread(target=self._serve, daemon=True).start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self.server.close()

    def _serve(self) -> None:
        self.server.settimeout(0.2)
        while not self._stop.is_set():
            try:
                client, _ = self.server.accept()
            except OSError:
                continue
            if time.monotonic() < self.up_at:  # still booting: no answer
                client.close()
                continue
            threading.Thread(target=self._session, args=(client,), daemon=True).start()

    def _reading_mg(self, index: int) -> np.ndarray:
        body = self.directions[index % len(self.directions)] * self.field_ut
        return self.truth.read(body[None, :], self.rng)[0] / UT_PER_MG

    def _gravity_mg(self, index: int) -> np.ndarray:
        return self.gravity_mg[index % len(self.gravity_mg)]

    def _session(self, client: socket.socket) -> None:
        # the one stream this session sends, if any: a STREAM or STOP ends the one before it before it answers,
        # so two streams never interleave their stamps (a streamer woken late once sent on beside the next)
        streamer: list[tuple[threading.Thread, threading.Event]] = []
        last_sent = [-1]  # the last sample sent: a stream asked again starts after it, never with it again
        with client, client.makefile("rw", encoding="ascii", newline="\n") as wire:
            send_lock = threading.Lock()

            def send(line: str) -> None:
                with send_lock:
                    wire.write(line + "\n")
                    wire.flush()

            def stop_streaming() -> None:
                while streamer:
                    thread, stop = streamer.pop()
                    stop.set()
                    thread.join()

            def stream(hz: float, stop: threading.Event) -> None:
                # each of the sensor's samples once, stamped with its own time: a simulator starved of the CPU
                # sends the samples it owes in order when it wakes (as a board's UART buffer does), never the
                # same instant twice
                step = max(1, round(SENSOR_HZ / min(hz, SENSOR_HZ)))
                index = max(int((time.monotonic() - self.booted_at) * SENSOR_HZ), last_sent[0] + 1)
                while not stop.is_set() and not self._stop.is_set():
                    while index <= (time.monotonic() - self.booted_at) * SENSOR_HZ:
                        x, y, z = self._reading_mg(index)
                        ax, ay, az = self._gravity_mg(index)
                        send(f"M {index * 1000 // int(SENSOR_HZ)} {x:.1f} {y:.1f} {z:.1f} {ax:.1f} {ay:.1f} {az:.1f}")
                        last_sent[0] = index
                        index += step
                    stop.wait(max(0.0, self.booted_at + index / SENSOR_HZ - time.monotonic()))

            for line in wire:
                parts = line.split()
                if not parts:
                    continue
                head, args = parts[0].upper(), parts[1:]
                try:
                    if head == "ID?":
                        send("ID ACME-MAG 1.2.0 0x4A21")
                    elif head == "STREAM":
                        stop_streaming()
                        stop = threading.Event()
                        thread = threading.Thread(target=stream, args=(float(args[0]), stop), daemon=True)
                        streamer.append((thread, stop))
                        thread.start()
                    elif head == "STOP":
                        stop_streaming()
                        send("OK STOP")
                    elif head == "GET":
                        known = args[0] in self.ram
                        send(f"VAL {args[0]} {self.ram[args[0]]!r}" if known else f"ERR unknown {args[0]}")
                    elif head == "SET":
                        if args[0] not in self.ram:
                            send(f"ERR unknown {args[0]}")
                            continue
                        with self.lock:
                            self.ram[args[0]] = float(np.float32(float(args[1])))
                        send(f"VAL {args[0]} {self.ram[args[0]]!r}")
                    elif head == "SAVE":
                        self.flash.write_text(json.dumps(self.ram))
                        send("OK SAVE")
                    elif head == "UPTIME?":
                        send(f"UPTIME {time.monotonic() - self.booted_at:.3f}")
                    elif head == "CAL?":
                        raw = self._reading_mg(int(self.rng.integers(len(self.directions))))
                        s = np.eye(3)
                        for name, i, j in MATRIX:
                            s[i, j] = s[j, i] = self.ram[name]
                        ofs = np.array([self.ram["OFS_X"], self.ram["OFS_Y"], self.ram["OFS_Z"]])
                        x, y, z = s @ (raw + ofs)
                        send(f"C {x:.2f} {y:.2f} {z:.2f}")
                    elif head == "TEMP?":
                        send(f"TEMP {self.board_temp_c:.1f}")
                    elif head == "REBOOT":
                        send("OK REBOOT")
                        stop_streaming()
                        with self.lock:
                            self._boot()
                        return
                    else:
                        send(f"ERR unknown command {head}")
                except (IndexError, ValueError):
                    send(f"ERR bad arguments for {head}")
            stop_streaming()  # the station hung up: nothing streams to a closed socket


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--port", type=int, default=7000)
    parser.add_argument("--flash", default="acme-flash.json")
    parser.add_argument("--board-temp-c", type=float, default=41.5, help="what the board's TEMP? answers")
    args = parser.parse_args()
    sim = AcmeSim(Path(args.flash), args.port, board_temp_c=args.board_temp_c).start()
    print(f"listening on {sim.connection}", flush=True)
    try:
        while True:
            time.sleep(1)
    except KeyboardInterrupt:
        sim.stop()


if __name__ == "__main__":
    main()
