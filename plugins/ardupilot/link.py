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
import socket

from pymavlink import mavutil

from magline.plugin import (
    SERIAL_HINT,
    SLICE_S,
    DutError,
    LinkError,
    Refusals,
    SerialAddress,
    SerialAddressError,
    SerialPortWatch,
    StationFault,
    UnansweredRequest,
    float32_equal,
    prove_unechoed_write,
    stall_s,
)

ML = mavutil.mavlink
GCS_SYSTEM, GCS_COMPONENT = 255, 190
RESULT_NAMES = {v: k.removeprefix("MAV_RESULT_") for k, v in vars(ML).items() if k.startswith("MAV_RESULT_")
                and isinstance(v, int)}
# An autopilot sends HEARTBEAT at 1 Hz: this long without any message means the link is gone.
SILENCE_S = 2.5



class LinkClosed(ConnectionError):
    """The vehicle closed the TCP connection (it died, lost power or rebooted)."""


class NotKnown(DutError):
    """The firmware has no parameter of that name: its reads went unanswered while the reads sent after
    each were answered (the unit's firmware cannot hold what the station must write or check: FAIL)."""


class DeadlineTcp(mavutil.mavtcp):
    """pymavlink's TCP client with a connect deadline and EOF taken as a closed link.

    Why: ``mavtcp`` connects with a blocking ``connect()`` (about 130 s against a port that never
    accepts, however short the station's deadline) and, on EOF, prints "EOF on TCP socket" and
    returns nothing — so a poll loop on a closed socket prints it hundreds of thousands of times.
    """

    def __init__(self, device: str, connect_timeout_s: float, **kwargs) -> None:
        self.connect_timeout_s = max(connect_timeout_s, 0.05)
        super().__init__(device, autoreconnect=False, retries=0, **kwargs)

    def do_connect(self) -> None:
        self.port = socket.create_connection(self.destination_addr, timeout=self.connect_timeout_s)
        self.port.setblocking(False)
        self.port.setsockopt(socket.SOL_TCP, socket.TCP_NODELAY, 1)

    def handle_eof(self) -> None:
        raise LinkClosed("the vehicle closed the TCP connection")

    def handle_disconnect(self) -> None:
        raise LinkClosed("the TCP connection was reset by the vehicle")


def pymavlink_device(connection: str) -> tuple[str, int]:
    """Station connection string → (pymavlink device, baud).

    ``tcp:HOST:PORT``, ``udpin:HOST:PORT``, ``udpout:HOST:PORT`` pass through;
    ``serial:/dev/serial/by-path/…:115200`` (or a bare device path) names a serial port, opened by
    its kernel node at each opening (:class:`~magline.plugin.SerialPortWatch`).
    """
    try:
        serial = SerialAddress.parse(connection)
    except SerialAddressError as exc:
        raise StationFault(str(exc)) from None  # the station file's mistake, not the unit's: an ERROR
    if serial is not None:
        return serial.path, serial.baud
    if connection.startswith(("tcp:", "udpin:", "udpout:", "udp:")):
        return connection, 115200
    raise StationFault(f"connection {connection!r}: expected tcp:HOST:PORT, udpin:HOST:PORT, udpout:HOST:PORT "
                   "or serial:DEVICE:BAUD")


class ArduPilotLink:
    """One MAVLink connection to the autopilot component (reopened after a reboot)."""

    def __init__(self, connection: str, *, param_timeout_s: float = 1.0, param_retries: int = 5) -> None:
        self.connection = connection
        self.device, self.baud = pymavlink_device(connection)
        serial = self.device.startswith("/")  # pymavlink_device gives a serial port as its device path
        self.port = SerialPortWatch(SerialAddress(self.device, self.baud)) if serial else None
        self.param_timeout_s = param_timeout_s
        self.param_retries = param_retries
        self.conn: Any = None
        self.target_system = 1
        self.target_component = ML.MAV_COMP_ID_AUTOPILOT1
        self._next_heartbeat = 0.0
        self.last_rx = 0.0  # monotonic time of the last message from the vehicle
        self.stalled_s = 0.0  # this process's own stalls since then (core/links/listening.py)
        self.statustexts: list[str] = []
        self.param_count = 1  # how many parameters the firmware has (each PARAM_VALUE says it)
        self._next_index = 0  # the last index read by :meth:`_ask`

    # ------------------------------------------------------------------ connection
    def open(self, timeout_s: float, nothing_listens_s: float | None = None) -> Any:
        """Connect and wait for the autopilot's heartbeat; return it.  ``nothing_listens_s``: connections
        refused that long end it at once (:mod:`magline.core.links.refusals`; a first connection)."""
        deadline = time.monotonic() + timeout_s
        last_error = "no heartbeat"
        refusals = Refusals(nothing_listens_s)
        while (remaining := deadline - time.monotonic()) > 0:
            try:
                device = self.port.ready(remaining).device if self.port is not None else self.device
                self.conn = self._connect(device, remaining)
            except OSError as exc:  # refused while the vehicle boots; try again until the deadline
                if refusals.over(exc):
                    raise LinkError(refusals.words(self.connection)) from None
                last_error = _socket_error(exc)
                time.sleep(min(0.2, max(deadline - time.monotonic(), 0.0)))
                continue
            try:
                heartbeat = self._wait_autopilot_heartbeat(min(deadline, time.monotonic() + 2.0))
            except LinkError as exc:
                heartbeat, last_error = None, str(exc)
            if heartbeat is not None:
                return heartbeat
            last_error = "connected, but no autopilot heartbeat"
            if self.port is not None:
                last_error += f"; {SERIAL_HINT}"
            self.close()
        raise LinkError(f"no ArduPilot vehicle answered on {self.connection} within {timeout_s:g} s ({last_error})")

    def _connect(self, device: str, timeout_s: float) -> Any:
        if device.startswith("tcp:"):
            return DeadlineTcp(device.removeprefix("tcp:"), timeout_s, source_system=GCS_SYSTEM,
                               source_component=GCS_COMPONENT)
        return mavutil.mavlink_connection(device, baud=self.baud, source_system=GCS_SYSTEM,
                                          source_component=GCS_COMPONENT, retries=0, autoreconnect=False)

    def _wait_autopilot_heartbeat(self, deadline: float) -> Any | None:
        while time.monotonic() < deadline:
            # any system id: a vehicle need not be system 1 (SYSID_THISMAV), and after a power cycle the
            # backend compares who answers with the unit it tested
            msg = self.recv("HEARTBEAT", deadline - time.monotonic(), any_system=True)
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
                raise self._lost(exc) from exc

    def recv(self, kind: str | list[str], timeout_s: float, any_system: bool = False) -> Any | None:
        """Next message of ``kind`` from the vehicle (``any_system``: from any) within ``timeout_s``
        (heartbeats keep going out meanwhile)."""
        if self.conn is None:
            raise LinkError(f"link to {self.connection} is closed")
        deadline = time.monotonic() + max(timeout_s, 0.0)
        kinds = {kind} if isinstance(kind, str) else set(kind)
        while True:
            self._beat()
            wait = min(SLICE_S, max(deadline - time.monotonic(), 0.001))
            asked = time.monotonic()
            try:
                msg = self.conn.recv_match(blocking=True, timeout=wait)
            except OSError as exc:
                raise self._lost(exc) from exc
            stalled = stall_s(asked, wait)
            if stalled:  # not listening (core/links/listening.py): the vehicle's messages wait in the socket
                deadline += stalled
                self.stalled_s += stalled
            if msg is not None:
                self.last_rx, self.stalled_s = time.monotonic(), 0.0
                if msg.get_type() == "STATUSTEXT":
                    self.statustexts.append(msg.text)
                if msg.get_type() in kinds and (any_system or msg.get_srcSystem() == self.target_system):
                    return msg
            if time.monotonic() >= deadline:
                return None

    def drain(self) -> None:
        """Drop what is queued (stale echoes, old stream samples); status texts are still collected."""
        try:
            while self.conn is not None and (msg := self.conn.recv_match(blocking=False)) is not None:
                self.last_rx, self.stalled_s = time.monotonic(), 0.0
                if msg.get_type() == "STATUSTEXT":
                    self.statustexts.append(msg.text)
        except OSError as exc:
            raise self._lost(exc) from exc

    def _lost(self, exc: OSError) -> LinkError:
        """The socket failed or the vehicle closed it: the link is gone now, not at the next timeout."""
        self.close()
        return LinkError(f"link to {self.connection} lost: {_socket_error(exc)}")

    def _send(self, method: str, *args: Any) -> None:
        if self.conn is None:
            raise LinkError(f"link to {self.connection} is closed")
        try:
            getattr(self.conn.mav, method)(*args)
        except OSError as exc:
            raise self._lost(exc) from exc

    def silent_for_s(self) -> float:
        """Seconds the station listened without hearing the vehicle (its 1 Hz heartbeat included):
        since the last message, less this process's own stalls (:mod:`magline.core.links.listening`)."""
        return time.monotonic() - self.last_rx - self.stalled_s

    def require_alive(self, what: str) -> None:
        """After a wait that got no answer: return when the vehicle still talks (its 1 Hz heartbeat
        within :data:`SILENCE_S`), else raise LinkError — a lost link is never reported as the
        firmware ignoring ``what``."""
        if self.conn is None:
            raise LinkError(f"link to {self.connection} is closed ({what})")
        remaining = SILENCE_S - self.silent_for_s()
        if remaining > 0:
            self.recv("HEARTBEAT", remaining)  # any message on the way refreshes last_rx
        if self.silent_for_s() > SILENCE_S:
            raise LinkError(f"link to {self.connection} lost: nothing received for {self.silent_for_s():.0f} s "
                            f"({what})")

    # ------------------------------------------------------------------ parameters (C-cast)
    def get(self, name: str) -> float:
        """PARAM_REQUEST_READ by name, asked five times, the wait doubling to at most 4× (1, 2, 4, 4, 4 s by
        default): a late answer on a congested link or a loaded station is not an absent one.

        Why five: a unit reads some 50 parameters, and a read unanswered every time is an ERROR.  With
        three tries on a link losing 2 % of its frames (the fault table's ``lossy`` row) one good unit in
        1,000 was booked ERROR (COMPASS_EXTERNAL, three answers lost).  Five put it at 50 · 0.04⁵ ≈ 5·10⁻⁶
        a unit even where the requests are lost as often as the answers.

        A name this firmware lacks is told without waiting those out (:class:`NotKnown`): ArduPilot drops
        such a read without a reply, but it answers reads one after another in the order they came
        (``GCS_Param.cpp``: one queue of requests, one of replies).  After the first wait, each request
        for ``name`` is followed by a read of another parameter by its index; that one's answer, come
        without ``name``'s before it, proves that request was read and left unanswered.  As many such
        proofs as the read has tries (each as unlikely as a lost answer) make the name unknown to the
        firmware; a silent vehicle proves nothing and still ends as before."""
        asked: set[int] = set()  # the indexes read after a request for ``name``, in every round of this read
        overtaken: set[int] = set()  # those answered where ``name``'s answer should have come first
        for attempt in range(self.param_retries):
            round_asked = self._ask(name, follow=attempt > 0)
            asked |= round_asked
            deadline = time.monotonic() + self.param_timeout_s * min(2 ** attempt, 4)
            while (msg := self.recv("PARAM_VALUE", deadline - time.monotonic())) is not None:
                self.param_count = max(self.param_count, int(msg.param_count))
                if msg.param_id == name:
                    return float(msg.param_value)
                if msg.param_index in asked:
                    overtaken.add(msg.param_index)
                    if len(overtaken) >= self.param_retries:
                        raise NotKnown(f"this firmware has no parameter {name}: {len(overtaken)} reads of it went "
                                       "unanswered while the reads sent after each were answered")
                    if overtaken >= round_asked:
                        break  # every request of this round was read: ask again at once
        self.require_alive(f"reading {name}")
        raise UnansweredRequest(f"parameter {name} could not be read: {self.param_retries} requests went unanswered "
                                "while the vehicle otherwise answers (answers lost on the link, or a vehicle that "
                                "answers no reads): the unit is not judged")

    def _ask(self, name: str, follow: bool) -> set[int]:
        """Send the read of ``name``; with ``follow``, as many times as the read has tries, each followed by
        a read by index (a fresh index each, so that a late answer to an earlier read is never taken for
        it).  Returns the indexes asked."""
        if not follow:
            self._send("param_request_read_send", self.target_system, self.target_component, name.encode(), -1)
            return set()
        asked: set[int] = set()
        for _ in range(self.param_retries):
            index = self._next_index = (self._next_index + 1) % max(self.param_count, 1)
            self._send("param_request_read_send", self.target_system, self.target_component, name.encode(), -1)
            self._send("param_request_read_send", self.target_system, self.target_component, b"", index)
            asked.add(index)
        return asked

    def set(self, name: str, value: float) -> float:
        """C-cast PARAM_SET; return the echoed value once an echo with this name and value arrives."""
        if not math.isfinite(value):
            raise DutError(f"refusing to write {name} = {value}: not a finite number")
        if self.port is not None:
            self.port.require_same()  # nothing is written through a port that now names another board
        echoed: float | None = None
        for _ in range(self.param_retries):
            self.drain()  # an earlier vector echo may carry this name with its old value
            echoed = None
            self._send("param_set_send", self.target_system, self.target_component, name.encode(), float(value),
                       ML.MAV_PARAM_TYPE_REAL32)  # the type is ignored by ArduPilot
            deadline = time.monotonic() + self.param_timeout_s
            while (msg := self.recv("PARAM_VALUE", deadline - time.monotonic())) is not None:
                if msg.param_id != name:
                    continue
                echoed = float(msg.param_value)
                if float32_equal(echoed, value):
                    return echoed
        if echoed is None:  # the echoes lost, the write ignored, or a name this firmware does not know
            self.require_alive(f"writing {name}")
            return float(prove_unechoed_write(
                name, float(value), f"PARAM_SET {name} = {value:g} got no echo while the vehicle was otherwise "
                "answering", lambda: self.get(name)))
        raise DutError(f"PARAM_SET {name} = {value:g} was answered with {echoed:g}: the autopilot refused the value")

    # ------------------------------------------------------------------ commands
    def command(self, command: int, *params: float, timeout_s: float = 2.0) -> int:
        """COMMAND_LONG with retries; return the ACK's MAV_RESULT."""
        p = [*params, *([0.0] * (7 - len(params)))]
        for confirmation in range(3):
            self._send("command_long_send", self.target_system, self.target_component, command, confirmation, *p)
            deadline = time.monotonic() + timeout_s / 3
            while (msg := self.recv("COMMAND_ACK", deadline - time.monotonic())) is not None:
                if msg.command == command:
                    return int(msg.result)
        self.require_alive(f"command {command}")
        # ArduPilot acknowledges every COMMAND_LONG, an unsupported one too: silence is answers lost, not a no
        raise UnansweredRequest(f"command {command} got no COMMAND_ACK within {timeout_s:.1f} s while the vehicle "
                                "otherwise answers: the unit is not judged")

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


def _socket_error(exc: OSError) -> str:
    """An operator-readable reason for a socket failure (no Python class names)."""
    if isinstance(exc, ConnectionRefusedError):
        return "connection refused: nothing listens on that port"
    if isinstance(exc, TimeoutError | socket.timeout):
        return "the port does not accept connections"
    if isinstance(exc, LinkClosed):
        return str(exc)
    return exc.strerror or str(exc) or "socket error"
