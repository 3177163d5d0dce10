"""Every command sequence of the README runs as written (issue 31), each simulator with its shipped
defaults, on free loopback ports instead of the fixed ones (several test workers run side by side):
the ports, and the folder simulated USB boards name their ports in, are rewritten in the commands and
in a copy of the station file, nothing else."""

from __future__ import annotations

import random
import re
import shlex
import socket
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import REPO

MAGLINE = [str(Path(sys.executable).with_name("magline"))]
DEFAULT_LISTEN = {"px4": "udp:127.0.0.1:14550", "ardupilot": "tcp:127.0.0.1:5760", "coil": "tcp:127.0.0.1:5026",
                  "gimbal": "tcp:127.0.0.1:5030", "inav": "tcp:127.0.0.1:5760", "turntable": "tcp:127.0.0.1:5050"}
PORT = re.compile(r"127\.0\.0\.1(:|::)(\d{4,5})")
USB_ROOT = "/tmp/magline-usb"  # where the walkthroughs' simulated boards lay out their udev-style names


def readme_sequences() -> list[tuple[str, list[str], str]]:
    """(name, simulator commands, run command) for each sequence: the shell blocks of the README and
    of every page under docs/, and the four-slot station file's own commented commands the docs point to."""
    text = "\n".join(p.read_text(encoding="utf-8") for p in [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))])
    sequences = []
    for block in re.findall(r"```sh\n(.*?)```", text, re.S):
        sims: list[str] = []
        for line in block.splitlines():
            command = line.split("#")[0].strip()
            if command.startswith("magline sim "):
                sims.append(command)
            elif command.startswith("magline run stations/") and sims:
                sequences.append((command.split()[2], sims, command))
                sims = []
    for name in ("slots-sim.yaml", "usb-slots-sim.yaml"):
        slots = (REPO / "stations" / name).read_text(encoding="utf-8")
        commented = [re.sub(r"\s+\(.*\)$", "", line.lstrip("# ").strip()) for line in slots.splitlines()
                     if line.startswith("#   magline ")]
        sequences.append((f"stations/{name}", [c for c in commented if c.startswith("magline sim")],
                          next(c for c in commented if c.startswith("magline run"))))
    return sequences


def free_port() -> int:
    """A port free for both TCP and UDP (a station may reach a simulator over either), drawn below the
    kernel's ephemeral range.  Why below: a port the kernel handed out is one it hands out again — to any
    worker's next outgoing UDP socket — between this check and the simulator binding it (seen twice in suite
    runs: "Address already in use"); below the range only another explicit draw can take it."""
    first_ephemeral = int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])
    draw = random.Random()  # not the suite's seed: each worker draws its own ports
    while True:
        port = draw.randrange(10_000, first_ephemeral)
        with socket.socket() as tcp, socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as udp:
            try:
                tcp.bind(("127.0.0.1", port))
                udp.bind(("127.0.0.1", port))
            except OSError:
                continue
            return port


@pytest.mark.parametrize(("name", "sims", "run"), readme_sequences(), ids=lambda v: v if isinstance(v, str) else "")
def test_a_readme_walkthrough_passes_as_written(tmp_path, name, sims, run):
    sims = [c if "--listen" in c or c.split()[2] not in DEFAULT_LISTEN else
            f"{c} --listen {DEFAULT_LISTEN[c.split()[2]]}" for c in sims]
    station_text = (REPO / name).read_text(encoding="utf-8")
    ports = {p for _, p in PORT.findall(" ".join(sims) + station_text)}
    ports |= {"5027"} if any(c.split()[2] == "coil" for c in sims) else set()
    moved = {p: str(free_port()) for p in ports}

    def rewrite(text: str) -> str:  # free ports, and the serial ports' names in this test's own folder
        text = PORT.sub(lambda m: f"127.0.0.1{m.group(1)}{moved[m.group(2)]}", text)
        return text.replace(USB_ROOT, str(tmp_path / "usb"))

    station = tmp_path / Path(name).name
    station.write_text(rewrite(station_text), encoding="utf-8")
    started = []
    try:
        for command in sims:
            argv = shlex.split(rewrite(command))
            if argv[2] == "coil" and "--fluxgate" not in argv:
                argv += ["--fluxgate", f"tcp:127.0.0.1:{moved['5027']}"]
            sim = subprocess.Popen(MAGLINE + argv[1:], cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                   text=True)
            started.append(sim)
            first = sim.stdout.readline()
            assert first.startswith("listening on"), f"{command}: {first}{sim.stdout.read() if sim.poll() else ''}"
        argv = shlex.split(run)
        argv[2] = str(station)
        done = subprocess.run(MAGLINE + argv[1:], cwd=tmp_path, capture_output=True, text=True, timeout=300,
                              stdin=subprocess.DEVNULL)
        assert done.returncode == 0, f"{run} exited {done.returncode}:\n{done.stdout[-3000:]}\n{done.stderr[-2000:]}"
    finally:
        for sim in started:
            sim.terminate()
        for sim in started:
            try:
                sim.wait(10)
            except subprocess.TimeoutExpired:
                sim.kill()
