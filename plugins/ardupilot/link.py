"""A pymavlink link to an ArduPilot vehicle with the parameter and command protocol done right.

Why a class of our own around ``mavutil``: pymavlink's helpers accept any PARAM_VALUE with the
right name as a confirmation (``mavset``) and byte-pack integers when given an integer type,
which ArduPilot stores as 0.  Here every set is C-cast, confirmed only by an echo carrying the
same name *and* the new value (ArduPilot answers a vector element with all three elements and
sends unsolicited values after boot), and every wait has a deadline and a message that names
what did not arrive.
"""

from __future__ import annotations

import math
import os
import time
from typing import Any

os.environ.setdefault("MAVLINK20", "1")  # PARAM_ERROR and v2 framing; must precede the import

import contextlib

from pymavlink import mavutil

from magline.core.dut import DutError

ML = mavutil.mavlink
GCS_SYSTEM, GCS_COMPONENT = 255, 190
RESULT_NAMES = {v: k.removeprefix("MAV_RESULT_") for k, v in vars(ML).items() if k.startswith("MAV_RESULT_")
                and isinstance(v, int)}


def float32_equal(a: float, b: float) -> bool:
    """Equal at float32 precision (1.05 reads back as 1.0499999523)."""
    return math.isclose(a, b, rel_tol=1e-6, abs_tol=1e-6)


def pymavlink_device(connection: str) -> tuple[str, int]:
    """Station connection string → (pymavlink device, baud).

    ``tcp:HOST:PORT``, ``udpin:HOST:PORT``, ``udpout:HOST:PORT`` pass through;
    ``serial:/dev/ttyACM0:115200`` (or a bare device path) opens a serial port.
    """
    if connection.startswith("serial:"):
        device, _, baud = connection.removeprefix("serial:").rpartition(":")
        if not device:
            device, baud = baud, "115200"
        return device, int(baud)
    if connection.startswith(("tcp:", "udpin:", "udpout:", "udp:", "/dev/", "COM")):
        return connection, 115200
    raise DutError(f"connection {connection!r}: expected tcp:HOST:PORT, udpin:HOST:PORT, udpout:HOST:PORT "
                   "or serial:DEVICE:BAUD")


class ArduPilotLink:
    """One MAVLink connection to the autopilot component (reopened after a reboot)."""

    def __init__(self, connection: str, *, param_timeout_s: float = 1.0, param_retries: int = 3) -> None:
        self.connection = connection
        self.device, self.baud = pymavlink_device(connection)
        self.param_timeout_s = param_timeout_s
        self.param_retries = param_retries
        self.conn: Any = None
        self.target_system = 1
        self.target_component = ML.MAV_COMP_ID_AUTOPILOT1
        self._next_heartbeat = 0.0
        self.statustexts: list[str] = []

    # ------------------------------------------------------------------ connection
    def open(self, timeout_s: float) -> Any:
        """Connect and wait for the autopilot's heartbeat; return it."""
        deadline = time.monotonic() + timeout_s
        last_error = "no heartbeat"
        while time.monotonic() < deadline:
            try:
                self.conn = mavutil.mavlink_connection(self.device, baud=self.baud, source_system=GCS_SYSTEM,
                                                       source_component=GCS_COMPONENT, retries=0, autoreconnect=False)
            except OSError as exc:  # refused while the vehicle boots; try again until the deadline
                last_error = f"{type(exc).__name__}: {exc}"
                time.sleep(0.2)
                continue
            heartbeat = self._wait_autopilot_heartbeat(min(deadline, time.monotonic() + 2.0))
            if heartbeat is not None:
                return heartbeat
            last_error = "connected, but no autopilot heartbeat"
            self.close()
        raise DutError(f"no ArduPilot vehicle answered on {self.connection} within {timeout_s:.0f} s ({last_error})")

    def _wait_autopilot_heartbeat(self, deadline: float) -> Any | None:
        while time.monotonic() < deadline:
            msg = self.recv("HEARTBEAT", deadline - time.monotonic())
            if msg is not None and msg.get_srcComponent() == ML.MAV_COMP_ID_AUTOPILOT1 \
                    and msg.autopilot != ML.MAV_AUTOPILOT_INVALID:
                self.target_system = msg.get_srcSystem()
                self.target_component = msg.get_srcComponent()  # pymavlink would leave 0 (broadcast)
                return msg
        return None

    def close(self) -> None:
        if self.conn is not None:
            with contextlib.suppress(OSError):
                self.conn.close()
            self.conn = None

    # ------------------------------------------------------------------ receiving
    def _beat(self) -> None:
        now = time.monotonic()
        if now >= self._next_heartbeat:
            self._next_heartbeat = now + 1.0
            try:
                self.conn.mav.heartbeat_send(ML.MAV_TYPE_GCS, ML.MAV_AUTOPILOT_INVALID, 0, 0, ML.MAV_STATE_ACTIVE)
            except OSError as exc:
                raise DutError(f"link to {self.connection} lost: {exc}") from exc

    def recv(self, kind: str | list[str], timeout_s: float) -> Any | None:
        """Next message of ``kind`` within ``timeout_s`` (heartbeats keep going out meanwhile)."""
        if self.conn is None:
            raise DutError(f"link to {self.connection} is closed")
        deadline = time.monotonic() + max(timeout_s, 0.0)
        kinds = {kind} if isinstance(kind, str) else set(kind)
        while True:
            self._beat()
            try:
                msg = self.conn.recv_match(blocking=True, timeout=min(0.2, max(deadline - time.monotonic(), 0.001)))
            except OSError as exc:
                raise DutError(f"link to {self.connection} lost: {exc}") from exc
            if msg is not None:
                if msg.get_type() == "STATUSTEXT":
                    self.statustexts.append(msg.text)
                if msg.get_type() in kinds and msg.get_srcSystem() == self.target_system:
                    return msg
            if time.monotonic() >= deadline:
                return None

    def drain(self) -> None:
        """Drop what is queued (stale echoes, old stream samples); status texts are still collected."""
        while self.conn is not None and (msg := self.conn.recv_match(blocking=False)) is not None:
            if msg.get_type() == "STATUSTEXT":
                self.statustexts.append(msg.text)

    # ------------------------------------------------------------------ parameters (C-cast)
    def get(self, name: str) -> float:
        for _ in range(self.param_retries):
            self.conn.mav.param_request_read_send(self.target_system, self.target_component, name.encode(), -1)
            deadline = time.monotonic() + self.param_timeout_s
            while (msg := self.recv("PARAM_VALUE", deadline - time.monotonic())) is not None:
                if msg.param_id == name:
                    return float(msg.param_value)
        raise DutError(f"parameter {name} could not be read (no PARAM_VALUE; unknown name or link lost)")

    def set(self, name: str, value: float) -> float:
        """C-cast PARAM_SET; return the echoed value once an echo with this name and value arrives."""
        if not math.isfinite(value):
            raise DutError(f"refusing to write {name} = {value}: not a finite number")
        echoed: float | None = None
        for _ in range(self.param_retries):
            self.drain()  # an earlier vector echo may carry this name with its old value
            echoed = None
            self.conn.mav.param_set_send(self.target_system, self.target_component, name.encode(), float(value),
                                         ML.MAV_PARAM_TYPE_REAL32)  # the type is ignored by ArduPilot
            deadline = time.monotonic() + self.param_timeout_s
            while (msg := self.recv("PARAM_VALUE", deadline - time.monotonic())) is not None:
                if msg.param_id != name:
                    continue
                echoed = float(msg.param_value)
                if float32_equal(echoed, value):
                    return echoed
        if echoed is None:
            raise DutError(f"PARAM_SET {name} = {value:g} got no echo: ArduPilot ignores unknown names "
                           "without a reply (wrong parameter name for this firmware?) or the link is lost")
        raise DutError(f"PARAM_SET {name} = {value:g} was answered with {echoed:g}: the autopilot refused the value")

    # ------------------------------------------------------------------ commands
    def command(self, command: int, *params: float, timeout_s: float = 2.0) -> int:
        """COMMAND_LONG with retries; return the ACK's MAV_RESULT."""
        p = [*params, *([0.0] * (7 - len(params)))]
        for confirmation in range(3):
            self.conn.mav.command_long_send(self.target_system, self.target_component, command, confirmation, *p)
            deadline = time.monotonic() + timeout_s / 3
            while (msg := self.recv("COMMAND_ACK", deadline - time.monotonic())) is not None:
                if msg.command == command:
                    return int(msg.result)
        raise DutError(f"command {command} got no COMMAND_ACK within {timeout_s:.1f} s")

    def require_accepted(self, command: int, what: str, *params: float, timeout_s: float = 2.0) -> None:
        result = self.command(command, *params, timeout_s=timeout_s)
        if result != ML.MAV_RESULT_ACCEPTED:
            raise DutError(f"{what} refused by the autopilot: {RESULT_NAMES.get(result, result)}")

    def request_message(self, msg_id: int, kind: str, timeout_s: float = 2.0) -> Any | None:
        self.require_accepted(ML.MAV_CMD_REQUEST_MESSAGE, f"request of {kind}", msg_id, timeout_s=timeout_s)
        return self.recv(kind, timeout_s)

    def set_message_interval(self, msg_id: int, rate_hz: float) -> None:
        interval = -1 if rate_hz <= 0 else 1e6 / rate_hz
        self.require_accepted(ML.MAV_CMD_SET_MESSAGE_INTERVAL, f"SET_MESSAGE_INTERVAL for message {msg_id}",
                              msg_id, interval)
