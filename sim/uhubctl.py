"""A stand-in for ``uhubctl`` (Debian's package) driving the simulated hub (:mod:`magline.sim.usb_hub`).

It takes the options the station's ``usb-hub`` power control gives the real program — ``-l LOCATION``,
``-p PORTS``, ``-a on|off|cycle|toggle|0|1|2|3``, ``-d DELAY`` — and prints what uhubctl prints (the
status before, the request, the status after), so the power control is tested against the program's
own words.  The hub is found through ``MAGLINE_SIM_USB_HUB`` (its ``tcp:HOST:PORT``).  Run it as
``python -m magline.sim.uhubctl``.
"""

from __future__ import annotations

import argparse
import os
import socket
import sys
import time

HUB_ENV = "MAGLINE_SIM_USB_HUB"
HUB_WORDS = "[1a40:0101 USB 2.0 Hub, USB 2.00, {ports} ports, ppps]"


class Hub:
    def __init__(self, address: str) -> None:
        _, host, port = address.split(":")
        self.sock = socket.create_connection((host, int(port)), timeout=5)
        self.file = self.sock.makefile("rw", encoding="utf-8", newline="\n")

    def ask(self, command: str) -> str:
        self.file.write(command + "\n")
        self.file.flush()
        return self.file.readline().strip()

    def tell(self, command: str) -> None:
        self.file.write(command + "\n")
        self.file.flush()


def status(hub: Hub, location: str, ports: list[int], heading: str) -> None:
    print(f"{heading} for hub {location} {HUB_WORDS.format(ports=hub.ask('PORTS?'))}")
    for port in ports:
        if hub.ask(f"PORT? {port}") == "1":
            device = hub.ask(f"DEV? {port}")
            print(f"  Port {port}: 0503 power highspeed enable connect" + (f" [{device}]" if device else ""))
        else:
            print(f"  Port {port}: 0000 off")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="uhubctl")
    parser.add_argument("-l", "--location", required=True)
    parser.add_argument("-p", "--ports", required=True)
    parser.add_argument("-a", "--action", required=True)
    parser.add_argument("-d", "--delay", type=float, default=2.0)
    args = parser.parse_args(argv)
    address = os.environ.get(HUB_ENV)
    if not address:
        print(f"No compatible devices detected ({HUB_ENV} names no simulated hub)!", file=sys.stderr)
        return 1
    hub = Hub(address)
    if hub.ask("LOC?") != args.location:
        print(f"No compatible devices detected at location {args.location}!", file=sys.stderr)
        return 1
    ports = [int(p) for p in args.ports.split(",")]
    action = {"0": "off", "1": "on", "2": "cycle", "3": "toggle"}.get(args.action, args.action)
    status(hub, args.location, ports, "Current status")
    steps = {"off": ["OFF"], "on": ["ON"], "cycle": ["OFF", "ON"]}.get(action)
    if action == "toggle":
        steps = ["OFF" if hub.ask(f"PORT? {ports[0]}") == "1" else "ON"]
    if steps is None:
        print(f"Invalid action: {args.action}", file=sys.stderr)
        return 1
    for index, state in enumerate(steps):
        if index:
            time.sleep(args.delay)
        print(f"Sent power {state.lower()} request")
        for port in ports:
            hub.tell(f"PORT {port},{state}")
        status(hub, args.location, ports, "New status")
    return 0


if __name__ == "__main__":
    sys.exit(main())
