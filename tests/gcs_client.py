"""A minimal pymavlink ground station for the simulator tests.

Deliberately independent of the px4 / ardupilot backends: the simulator is proven against a
plain client first, so that backend tests later rest on a simulator known to behave.
"""

from __future__ import annotations

import os
import struct
import time

os.environ.setdefault("MAVLINK20", "1")

from pymavlink import mavutil


def int_as_bytewise_float(value: int) -> float:
    return struct.unpack("<f", struct.pack("<i", value))[0]


def bytewise_float_as_int(value: float) -> int:
    return struct.unpack("<i", struct.pack("<f", value))[0]


class Gcs:
    """Connects to a simulator address (``udp:`` → we send first; ``tcp:`` → we connect)."""

    def __init__(self, address: str, timeout: float = 5.0) -> None:
        scheme, host, port = address.split(":")
        device = f"udpout:{host}:{port}" if scheme == "udp" else f"tcp:{host}:{port}"
        self.address = address
        self.conn = mavutil.mavlink_connection(device, source_system=255, source_component=190,
                                               autoreconnect=False)
        self.wait_heartbeat(timeout)

    def wait_heartbeat(self, timeout: float = 5.0):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.conn.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            msg = self.conn.recv_match(type="HEARTBEAT", blocking=True, timeout=0.3)
            if msg is not None:
                return msg
        raise TimeoutError(f"no heartbeat from {self.address}")

    def recv(self, kind: str | list[str], timeout: float = 2.0, **match):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            msg = self.conn.recv_match(type=kind, blocking=True, timeout=max(0.01, deadline - time.monotonic()))
            if msg is not None and all(getattr(msg, k) == v for k, v in match.items()):
                return msg
        return None

    def get(self, name: str, timeout: float = 2.0):
        self.conn.mav.param_request_read_send(1, 1, name.encode(), -1)
        return self.recv("PARAM_VALUE", timeout, param_id=name)

    def set(self, name: str, wire_value: float, ptype: int, timeout: float = 1.0):
        self.conn.mav.param_set_send(1, 1, name.encode(), wire_value, ptype)
        return self.recv("PARAM_VALUE", timeout, param_id=name)

    def command(self, command: int, *params: float, timeout: float = 2.0):
        p = [*params, *([0.0] * (7 - len(params)))]
        self.conn.mav.command_long_send(1, 1, command, 0, *p)
        return self.recv("COMMAND_ACK", timeout, command=command)

    def close(self) -> None:
        self.conn.close()
