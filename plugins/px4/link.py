"""A MAVSDK (4.x, in-process) link to a PX4 vehicle, with what MAVSDK lacks done over its
raw-MAVLink plugin (``MavlinkDirect``): SCALED_IMU2/3, PREFLIGHT_STORAGE, SET_MESSAGE_INTERVAL.

Two MAVSDK behaviours matter for a factory tool:
- its parameter client *caches* values; a read after a reboot can be answered from the cache of
  the previous boot without a single packet on the link.  A read-back that proves persistence
  therefore needs a fresh ``Mavsdk`` instance after the power cycle (:meth:`Px4Link.reopen`);
- ``set_param_*`` already waits for an echo of the same type and value and retries, and a
  PARAM_SET that PX4 drops (wrong type, unknown name) ends in ``TIMEOUT``.
"""

from __future__ import annotations

import json
import logging
import queue
import threading
import time
from typing import Any

from mavsdk import ComponentType, Configuration, ConnectionResult, Mavsdk, log_subscribe
from mavsdk.autopilot import Autopilot
from mavsdk.plugins.action.action import Action, ActionError, ActionResult
from mavsdk.plugins.info.info import Info
from mavsdk.plugins.mavlink_direct.mavlink_direct import MavlinkDirect, MavlinkDirectError, MavlinkMessage
from mavsdk.plugins.param.param import Param, ParamError
from mavsdk.plugins.shell.shell import Device, Shell
from pymavlink.dialects.v20 import common as mavlink

from magline.plugin import (
    SERIAL_HINT,
    DutError,
    LinkError,
    SerialAddress,
    SerialAddressError,
    SerialPortWatch,
    StationFault,
    UnansweredRequest,
    get_listening,
    prove_unechoed_write,
)

log = logging.getLogger("magline.px4.mavsdk")
# MAVSDK's results that mean the command was not answered, as opposed to answered with a no
UNANSWERED = (ActionResult.TIMEOUT, ActionResult.CONNECTION_ERROR, ActionResult.NO_SYSTEM)
COMMAND_ATTEMPTS = 2  # MAVSDK's own (six sends over 3 s) per attempt: PX4.command
GCS_SYSTEM, GCS_COMPONENT = 245, 190  # MAVSDK's ground-station identity
RESULTS = {n: e.name.removeprefix("MAV_RESULT_") for n, e in mavlink.enums["MAV_RESULT"].items()}
SHELL_PROMPTS = ("nsh> ", "pxh> ")  # NuttX boards; POSIX builds (which rarely answer over MAVLink)
SILENCE_S = 2.5  # PX4 sends HEARTBEAT at 1 Hz: this long without one means the link is gone
READ_ASKS = 2  # a parameter read MAVSDK gave up on is asked again once the vehicle is heard
TEMPORARILY_REJECTED = 1  # MAV_RESULT: the commander's worker thread is busy
WORKER_BUSY_S = 5.0  # how long a command for the worker thread is asked again while it is busy

_routed = False
# mavsdk_create / mavsdk_destroy of the native library are not safe to run on several threads at once:
# four slots connecting together segfaulted the station now and then (seen in the four-board slot test,
# once in five to ten runs).  Creating and destroying instances one at a time costs milliseconds.
NATIVE_LOCK = threading.Lock()


def _route_mavsdk_logs() -> None:
    """MAVSDK prints to stdout; send it to Python logging instead (once per process)."""
    global _routed
    if not _routed:
        levels = {0: logging.DEBUG, 1: logging.INFO, 2: logging.WARNING, 3: logging.ERROR}
        log_subscribe(lambda level, message, *_: log.log(levels.get(int(level), logging.INFO), message) or True)
        _routed = True



class NotListed(DutError):
    """The firmware has no such parameter: its own list of parameters lacks the name (a release older than the
    name, or a build without the module).  A fact of the unit's firmware, not a link's silence."""


class Px4Link:
    def __init__(self, url: str, *, connect_timeout_s: float = 10.0) -> None:
        self.url = url
        # a board on a serial port: opened by its kernel node (MAVSDK's URL takes no colons in a path, and
        # udev's by-path names have them), looked up again at each opening — it re-enumerates at a reboot
        try:
            serial = SerialAddress.parse(url)
        except SerialAddressError as exc:
            raise StationFault(str(exc)) from None  # the station file's mistake, not the unit's: an ERROR
        self.port = SerialPortWatch(serial) if serial is not None else None
        self.connect_timeout_s = connect_timeout_s
        self.mavsdk: Mavsdk | None = None
        self.system: Any = None
        self._listed: frozenset[str] | None = None  # the firmware's parameter names, once asked on this link
        self._list_asked = False
        self.target_system = 1
        self._shell_out: queue.Queue[str] = queue.Queue()
        self._shell_lock = threading.Lock()

    # ------------------------------------------------------------------ connection
    def open(self, timeout_s: float | None = None) -> None:
        _route_mavsdk_logs()
        timeout_s = self.connect_timeout_s if timeout_s is None else timeout_s
        deadline = time.monotonic() + timeout_s
        node = self._connect(deadline)
        while True:
            self.system = self.mavsdk.first_autopilot(self._listen_s(deadline))
            if self.system is not None:
                break
            if time.monotonic() >= deadline:
                self.close()
                hint = f"; {SERIAL_HINT}" if self.port is not None else ""
                raise LinkError(f"no PX4 vehicle answered on {self.url} within {timeout_s:g} s{hint}")
            if self.port is not None and not self.port.still_at(node):
                # the node went away (the board's reboot had not yet taken it when it was opened), or
                # another took its name: open what the name points at now
                self.close()
                node = self._connect(deadline)
        if self.system.autopilot_type() != Autopilot.PX4:
            kind = Autopilot(self.system.autopilot_type()).name
            self.close()
            raise StationFault(f"the vehicle on {self.url} is {kind}, not PX4; check the product's backend")
        self.target_system = self.system.get_system_id()
        self.param = Param(self.system)
        self._listed, self._list_asked = None, False
        self.action = Action(self.system)
        self.info = Info(self.system)
        self.direct = MavlinkDirect(self.system)
        self.shell_plugin = Shell(self.system)
        self.shell_plugin.subscribe_receive(lambda data, _: self._shell_out.put(data.data))

    def _connect(self, deadline: float) -> str | None:
        """A new MAVSDK instance on the link; for a serial port, on the node its name points at once the
        board is there (returned), waiting for it until ``deadline``."""
        while True:
            url = self.url
            node = None
            if self.port is not None:
                node = self.port.ready(max(deadline - time.monotonic(), 0.0)).device
                url = f"serial://{node}:{self.port.address.baud}"
            with NATIVE_LOCK:  # two Mavsdk instances created at once crash the process (slots connect together)
                self.mavsdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
            result = self.mavsdk.add_any_connection(url)
            if result == ConnectionResult.SUCCESS:
                return node
            self.close()
            if self.port is not None and not self.port.still_at(node) and time.monotonic() < deadline:
                continue  # the node went between the look and the opening (a reboot under way): look again
            raise StationFault(f"cannot open {url}: {ConnectionResult(result).name} (expected udpin://HOST:PORT, "
                               "udpout://HOST:PORT, tcpout://HOST:PORT or serial:DEV:BAUD)")

    def _listen_s(self, deadline: float) -> float:
        """How long to wait for the vehicle before looking again: all the time left on a network link,
        half a second on a serial port (whose node may vanish meanwhile)."""
        left = max(deadline - time.monotonic(), 0.05)
        return left if self.port is None else min(left, 0.5)

    def reopen(self, timeout_s: float) -> None:
        """A new MAVSDK instance: nothing cached from the previous boot can answer a read."""
        self.close()
        self.open(timeout_s)

    def close(self) -> None:
        if self.mavsdk is not None:
            with NATIVE_LOCK:
                self.mavsdk.destroy()
        self.mavsdk = None
        self.system = None

    @property
    def is_open(self) -> bool:
        return self.system is not None

    def require_alive(self, what: str) -> None:
        """After a wait that got no answer: return when the vehicle still sends its 1 Hz heartbeat,
        else raise LinkError — a lost link is never reported as the firmware ignoring ``what``."""
        if not self.is_open:
            raise LinkError(f"link to {self.url} is closed ({what})")
        inbox, handle = self.subscribe("HEARTBEAT")
        try:
            get_listening(inbox, SILENCE_S)
        except queue.Empty:
            raise LinkError(f"link to {self.url} lost: no heartbeat for {SILENCE_S:g} s ({what})") from None
        finally:
            self.unsubscribe(handle)

    def hardware_uid(self) -> int:
        """AUTOPILOT_VERSION's ``uid`` as MAVSDK's Info reports it (``legacy_uid``); 0 when not said."""
        for _ in range(10):  # like the version, it arrives shortly after discovery
            try:
                return int(self.info.get_identification().legacy_uid)
            except Exception:  # InfoError while the information is not in yet
                time.sleep(0.1)
        return 0

    def firmware(self) -> tuple[int, int, int] | None:
        for _ in range(10):  # AUTOPILOT_VERSION arrives shortly after discovery
            try:
                v = self.info.get_version()
                return v.flight_sw_major, v.flight_sw_minor, v.flight_sw_patch
            except Exception:  # InfoError while the information is not in yet
                time.sleep(0.1)
        return None

    # ------------------------------------------------------------------ parameters
    def get(self, name: str, is_int: bool) -> int | float:
        """The parameter's value.  A read MAVSDK gave up on (its own resends unanswered) is asked once more
        once the vehicle is heard again, as the ArduPilot backend asks five times: a station whose host fell
        behind its link for seconds (MAVSDK: "Heartbeats … timed out") had every resend's answer arrive too
        late, and ERRORed a good unit on a name the firmware has."""
        if not self.is_open:
            raise LinkError(f"link to {self.url} is closed (reading {name})")
        self._require_listed(name)
        asked = 0
        while True:
            asked += 1
            try:
                return self.param.get_param_int(name) if is_int else self.param.get_param_float(name)
            except ParamError as exc:
                if exc.result.name != "TIMEOUT":
                    raise DutError(f"parameter {name} could not be read: {exc.result.name}") from exc
                # PX4 1.13–1.16 drop an unknown name silently; so does a lossy link, or a host too late to listen
                self.listed_names()
                self._require_listed(name)
                # listed (or no list to be had): the answer was lost, or came too late — ask again once heard
                self.require_alive(f"reading {name}")
                if asked == READ_ASKS:
                    raise UnansweredRequest(
                        f"parameter {name} could not be read: no answer to {READ_ASKS} requests while the vehicle "
                        "otherwise answers (a name this firmware does not know, or answers lost on the link): the "
                        "unit is not judged") from exc

    def listed_names(self) -> frozenset[str] | None:
        """Every parameter name the firmware lists (PARAM_REQUEST_LIST; MAVSDK asks again for what the link
        lost, and answers only a whole list), asked once per link and only after a read went unanswered: an
        unknown name costs a read all its retries, and an older PX4 lacks several names the station asks
        for (CAL_MAGn_xODIAG before v1.12, CAL_MAGn_ROLL before v1.15), each of which took seconds.  None
        when the list cannot be had: the read is then asked again as before."""
        if not self._list_asked:
            self._list_asked = True
            try:
                found = self.param.get_all_params()
            except ParamError:
                return None
            names = [p.name for group in (found.int_params, found.float_params) for p in group]
            self._listed = frozenset(names) if names else None
        return self._listed

    def _require_listed(self, name: str) -> None:
        """NotListed when the firmware's list, once asked, lacks ``name``."""
        if self._listed is not None and name not in self._listed:
            raise NotListed(f"this PX4 has no parameter {name} (not in the list of its parameters)")

    def set(self, name: str, value: int | float, is_int: bool) -> int | float:
        """PARAM_SET with the exact type (INT32 byte-wise or REAL32); return the value read afterwards."""
        if self.port is not None:
            self.port.require_same()  # nothing is written through a port that now names another board
        try:
            if is_int:
                self.param.set_param_int(name, int(value))
            else:
                self.param.set_param_float(name, float(value))
        except ParamError as exc:
            if exc.result.name != "TIMEOUT":
                raise DutError(f"PARAM_SET {name} = {value!r} not confirmed: {exc.result.name}") from exc
            # no echo: the echoes lost, the write dropped (PX4 drops an unknown name or the wrong type without
            # a reply), or nothing arriving at all — the parameter read back tells which
            self.require_alive(f"writing {name}")
            prove_unechoed_write(name, int(value) if is_int else float(value),
                                 f"PARAM_SET {name} = {value!r} not confirmed: TIMEOUT while the vehicle was "
                                 "otherwise answering", lambda: self.get(name, is_int))
        return self.get(name, is_int)

    # ------------------------------------------------------------------ commands and raw messages
    def command(self, command: int, *params: float) -> int:
        """COMMAND_LONG; the ACK's MAV_RESULT.  MAVSDK sends it up to six times over 3 s; unanswered, it is sent
        again once (``COMMAND_ATTEMPTS``).  PX4 acknowledges every command it receives, an unsupported one
        too, so silence from a vehicle that otherwise answers is answers lost — a lossy link, or a host so
        loaded that they came after the wait — and proves nothing of the unit: :class:`UnansweredRequest`
        (ERROR), as ArduPilot's link says it."""
        p = [*params, *([0.0] * (7 - len(params)))]
        fields = {"target_system": self.target_system, "target_component": 1, "command": command,
                  "confirmation": 0, **{f"param{i + 1}": v for i, v in enumerate(p)}}
        for _ in range(COMMAND_ATTEMPTS):
            if not self.is_open:
                raise LinkError(f"link to {self.url} is closed (command {command})")
            try:
                ack = self.direct.send_command(MavlinkMessage("COMMAND_LONG", GCS_SYSTEM, GCS_COMPONENT,
                                                              self.target_system, 1, json.dumps(fields)))
            except MavlinkDirectError as exc:
                self.require_alive(f"command {command}")
                if exc.result.name != "TIMEOUT":
                    raise DutError(f"command {command} got no COMMAND_ACK ({exc.result.name})") from exc
                continue
            return int(json.loads(ack.fields_json)["result"])
        raise UnansweredRequest(f"command {command} got no COMMAND_ACK in {COMMAND_ATTEMPTS} waits of MAVSDK's (each "
                                "up to six sends over 3 s) while the vehicle otherwise answers: the unit is not judged")

    def require_accepted(self, command: int, what: str, *params: float) -> None:
        result = self.command(command, *params)
        if result != 0:
            raise DutError(f"{what} refused by the autopilot: {RESULTS.get(result, result)}")

    def require_accepted_by_worker(self, command: int, what: str, *params: float) -> None:
        """A command the commander runs on its worker thread (a parameter save, a calibration, a reset):
        refused with TEMPORARILY_REJECTED while that thread is busy — and it stays busy a moment after a
        calibration has said "done", until the commander's next cycle collects its result (seen on PX4
        SITL: the save right after the factory store's gyro calibration was refused).  Asked again until
        it is free, for :data:`WORKER_BUSY_S` at most."""
        deadline = time.monotonic() + WORKER_BUSY_S
        while True:
            result = self.command(command, *params)
            if result != TEMPORARILY_REJECTED or time.monotonic() > deadline:
                break
            time.sleep(0.1)
        if result != 0:
            raise DutError(f"{what} refused by the autopilot: {RESULTS.get(result, result)}")

    def subscribe(self, message: str) -> tuple[queue.Queue[dict], Any]:
        """Every ``message`` as a dict of its fields, into a queue; returns (queue, handle)."""
        inbox: queue.Queue[dict] = queue.Queue()
        handle = self.direct.subscribe_message(message, lambda msg, _: inbox.put(json.loads(msg.fields_json)))
        return inbox, handle

    def subscribe_all(self, messages: list[str]) -> tuple[queue.Queue[tuple[str, dict]], list[Any]]:
        """Several messages into one queue, in arrival order, as (name, fields); returns (queue, handles)."""
        inbox: queue.Queue[tuple[str, dict]] = queue.Queue()
        handles = [self.direct.subscribe_message(
            name, lambda msg, _, name=name: inbox.put((name, json.loads(msg.fields_json)))) for name in messages]
        return inbox, handles

    def unsubscribe(self, handle: Any) -> None:
        if self.is_open:
            self.direct.unsubscribe_message(handle)

    def reboot(self) -> None:
        """Command the reboot.  No answer (the ACK lost on the way, the board already going down) is not a
        refusal: the new boot decides (``await_boot`` proves it by its uptime, or the unit is an ERROR).
        Only an answer that says no is the autopilot refusing."""
        try:
            self.action.reboot()
        except ActionError as exc:
            result = exc.args[0] if exc.args else None
            if result in UNANSWERED:
                log.info("reboot: no acknowledgement (%s) — waiting for the new boot", result)
                return
            raise DutError(f"reboot refused by the autopilot: {exc}") from exc

    # ------------------------------------------------------------------ MAVLink shell
    def shell(self, command: str, timeout_s: float = 2.0) -> str:
        """Run one nsh command; return its output up to the next prompt."""
        with self._shell_lock:
            while not self._shell_out.empty():
                self._shell_out.get_nowait()
            self.shell_plugin.send(command, Device.SHELL)
            out = ""
            deadline = time.monotonic() + timeout_s
            while not any(p in out for p in SHELL_PROMPTS):
                try:
                    out += self._shell_out.get(timeout=max(deadline - time.monotonic(), 0.01))
                except queue.Empty:
                    raise StationFault(f"no answer from the PX4 shell to {command!r} within {timeout_s:g} s") from None
            return min((out.split(p)[0] for p in SHELL_PROMPTS if p in out), key=len)
