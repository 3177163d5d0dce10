"""The simulated flight controller's engine: link, MAVLink framing, power states, streams, commands.

What is common to both autopilots lives here; what differs (parameter table and encoding,
persistence rules, how the held calibration is applied, which messages carry which sensor)
is in :mod:`.px4` and :mod:`.ardupilot`.  One thread runs the board: it polls the socket,
handles whole frames (garbage and truncated frames are dropped by the parser, never fatal),
sends heartbeats and the requested streams, and advances timers (autosave, boot).

Power states::

    UP ──reboot command──▶ SHUTTING_DOWN ──(delay, running save finished)──▶ BOOTING ──boot time──▶ UP
    any ──power_off()──▶ OFF (RAM lost, an unfinished save is lost) ──power_on()──▶ BOOTING
"""

from __future__ import annotations

import enum
import functools
import math
import queue
import random
import threading
import time
from abc import ABC, abstractmethod
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray
from pymavlink.dialects.v20 import ardupilotmega as mavlink
from scipy.spatial.transform import Rotation

from magline.sim.faults import SimFaults
from magline.sim.magnetometers import SimMagnetometer, attitude, default_magnetometers, driver_rate_hz, ned_to_body
from magline.sim.params import ParamSpec, ParamTable, ParamValue
from magline.sim.schedule import BoardSchedule
from magline.sim.storage import NvStorage
from magline.sim.thermal import BoardWarmth
from magline.sim.transport import open_server
from magline.sim.truth import earth_field_ned

ACCEPTED, DENIED, UNSUPPORTED, FAILED = (
    mavlink.MAV_RESULT_ACCEPTED, mavlink.MAV_RESULT_DENIED,
    mavlink.MAV_RESULT_UNSUPPORTED, mavlink.MAV_RESULT_FAILED)
MAX_STREAM_HZ = 1000.0
POLL_S = 0.002  # how soon the loop looks again at a message due and held back
# the longest the loop waits for the station (with a bundle's window: BUNDLE_S more): the board's other timers
# are this late at most
TIMER_WAIT_S = 0.010
# How long after a message falls due the loop may wait for others to send with it, in one write.  Why: a board
# looping for each message woke, and woke its station, for each (three 100 Hz compass streams with their own
# jitter: 209 wake-ups a second, 100 bundled, ``benchmarks/sim_wakeups.py``).  PX4's MAVLink module does the
# same: it sends what fell due once per main loop, every 1.5–10 ms by the link's data rate
# (``_main_loop_delay``, src/modules/mavlink/mavlink_main.cpp).
# Each message keeps the instant it was computed and stamped at; only its bytes leave up to this much later.
BUNDLE_S = 0.004
UDP_BUNDLE_BYTES = 1400  # a bundle larger than this goes out in several datagrams, each holding whole frames
MOTOR_CRADLE_S = 3.0  # motors quiet this long, a new stream is a tumble out of the cradle


class Power(enum.Enum):
    UP = "up"
    SHUTTING_DOWN = "shutting down"
    BOOTING = "booting"
    OFF = "off"


def int16_mg(values_mg: NDArray) -> list[int]:
    """What both firmwares put into a MAVLink int16 mG field: a C conversion from float, which
    truncates toward zero (each axis reads on average 0.5 mG closer to zero), saturated at the type."""
    # in plain floats: three values at every streamed message, where NumPy's clip cost more than the arithmetic
    return [int(min(32767.0, max(-32768.0, v))) for v in np.asarray(values_mg, float).tolist()]


class _Wire:
    """File-like sink pymavlink writes packed frames to; applies the packet-loss fault."""

    def __init__(self, board: SimulatedAutopilot) -> None:
        self.board = board

    def write(self, data: bytes) -> None:
        self.board._transmit(data)


def least_seen_attitude(seen_dirs: NDArray, field_ned: NDArray) -> Rotation:
    """The attitude (body → NED) that shows the field in the body direction farthest from every
    direction in ``seen_dirs`` (unit rows): where a tumble's calibration is known least."""
    k = np.arange(600) + 0.5
    z = 1.0 - 2.0 * k / 600
    r = np.sqrt(1.0 - z * z)
    phi = np.pi * (1.0 + 5.0**0.5) * k
    candidates = np.column_stack([r * np.cos(phi), r * np.sin(phi), z])
    nearest = (candidates @ seen_dirs[:: max(1, len(seen_dirs) // 2000)].T).max(axis=1)
    body = candidates[int(np.argmin(nearest))]
    ned_to_body, _ = Rotation.align_vectors([body], [np.asarray(field_ned, float) / np.linalg.norm(field_ned)])
    return ned_to_body.inv()


class SimulatedAutopilot(ABC):
    """A flight controller on a real socket.  Use :meth:`start` / :meth:`stop` (or ``with``)."""

    flavour: str
    autopilot: int
    capabilities: int
    default_listen: str
    storage_name: str
    stream_sensor: ClassVar[dict[int, int]]  # message id → index into the detected sensors
    # How often the firmware reads its compass (None: each driver's own rate).  A stream requested
    # faster than this carries the same reading several times, as real vehicles do.
    firmware_mag_rate_hz: ClassVar[float | None] = None

    def __init__(self, listen: str | None = None, *, workdir: str | Path = ".",
                 magnetometers: list[SimMagnetometer] | None = None, mag_count: int = 1,
                 field_ut: float = 48.0, inclination_deg: float = 62.0,
                 motions: tuple[str, ...] | None = None, speed: float = 1.0, boot_time_s: float = 2.0,
                 faults: SimFaults | None = None, seed: int | None = None, system_id: int = 1,
                 save_duration_s: float = 0.05, field_provider: Callable[[], NDArray] | None = None,
                 mag_rate_hz: float | None = None, motion_source: str | None = None,
                 usb_aliases: tuple[str, ...] = (), usb_powered: bool = False) -> None:
        self.listen = listen or self.default_listen
        self.usb_aliases = usb_aliases  # more names of a serial port (a udev by-id link beside by-path)
        # where the board takes its power: a supply (power_off / power_on) and, ``usb_powered``, its USB port
        # (usb_power); it runs while either feeds it — a supply cut does not reboot a board on USB
        self.usb_powered = usb_powered
        self.supply_on = not usb_powered  # a board on USB alone has no supply until one switches on
        self.usb_on = usb_powered
        self.workdir = Path(workdir)
        self.rng = np.random.default_rng(seed)
        self.random = random.Random(seed)
        self.magnetometers = magnetometers or default_magnetometers(mag_count, self.rng)
        self.faults = faults or SimFaults()
        for index, (mounting, yaw_deg) in self.faults.mountings().items():
            if index < len(self.magnetometers):
                self.magnetometers[index].mount(mounting, (0.0, 0.0, yaw_deg))
        # the current through the board's power path, downstream of its current sensor (issue 46): the board's
        # own draw, a load's (``current_provider``, the simulated electronic load) and its motors' on a motor test
        self.idle_current_a = 0.0  # its own draw: part of the hard iron at rest, so 0 keeps the sensors' truth
        self.current_provider: Callable[[], float] | None = None
        self.current_scale = 1.0 + self.faults.current_sensor_pct / 100.0  # the board's current sensor's error
        self._motor_test: tuple[float, float] | None = None  # (throttle %, until) while a motor test runs
        self._peak_current_a = 0.0  # the largest current seen since boot (fault ``interference_remanence``)
        self._still: tuple[Rotation, float] | None = None  # held still in a fixture: (attitude, since)
        self._attitude_memo: tuple[tuple, Rotation] | None = None  # the last instant asked for, and its attitude
        self._matrix_memo: tuple[tuple, NDArray] | None = None  # the last instant asked for, and its NED → body
        self._still_by_motors = False  # … strapped in the cradle for a motor test (not a load's fixture)
        self._motors_commanded_at = 0.0
        # BATTERY_STATUS / SYS_STATUS on the board's clock; the scheduler's jitter draws from its own generator,
        # so the faults' draws (a dropped frame) are the ones a seed always gave
        self._status_streams = BoardSchedule(random.Random(None if seed is None else seed + 1))
        self._latency_s = {self.magnetometers[index].device_id: seconds
                           for index, seconds in self.faults.latencies_s().items() if index < len(self.magnetometers)}
        self.field_ned = earth_field_ned(field_ut, inclination_deg)
        self.field_ut = field_ut
        # ``shared``: the board is mounted on a (simulated) gimbal at ``motion_source`` and moves with it
        self.motions = tuple(motions or (("shared",) if motion_source else ("tumble",)))
        if "shared" in self.motions and not motion_source:
            raise ValueError("the shared motion needs motion_source (the gimbal simulator's tcp:HOST:PORT)")
        self.motion_source = motion_source
        self.follower = None
        self.speed = speed
        self.boot_time_s = boot_time_s
        self.system_id = system_id
        # the board's hardware UID (AUTOPILOT_VERSION.uid): one per simulated board, from its seed
        self.uid = 0x4D41474C_00000000 + ((seed or 0) & 0xFFFFFF) * 256 + system_id
        self.save_duration_s = save_duration_s
        self.field_provider = field_provider  # the board stands in a coil: its field, not a tumble
        self.mag_rate_hz = mag_rate_hz  # overrides the firmware's / driver's sensor rate
        self._held: dict[int, tuple[float, NDArray]] = {}  # device id → (next reading due, latest reading)
        self._quiet: dict[int, NDArray] = {}  # device id → the reading a quiet compass repeats at rest
        self._stuck: dict[int, NDArray] = {}  # device id → the reading a stuck compass repeats (mag_stuck_after_s)
        self.table = ParamTable(self.param_specs())
        self.mav = mavlink.MAVLink(_Wire(self), srcSystem=system_id, srcComponent=mavlink.MAV_COMP_ID_AUTOPILOT1)
        self.lock = threading.RLock()
        self.power = Power.OFF
        self.detected: list[SimMagnetometer] = []
        self.link = None
        self.link_dead = False
        self.bad_frames = 0
        self.boots = 0
        self._parsers: dict[object, mavlink.MAVLink] = {}
        self._streams = BoardSchedule(random.Random(None if seed is None else seed + 2))  # the sensor streams
        self._motion_index = -1
        self._seen_dirs: list[NDArray] = []  # the field's body directions the tumble showed since the last boot
        # after a power cycle: (attitude, the motion index at which the next tumble ends the rest)
        self._rest: tuple[Rotation, int] | None = None
        self._mag_stream_started: float | None = None
        self._t0 = time.monotonic()
        self._booted_at = self._t0
        warmup = self.faults.warmup()
        self.warmth = BoardWarmth(warmup[1], self._t0) if warmup else None  # fault ``mag_warmup`` only
        self._read_since_supply = False  # the compasses were read since the supply last changed
        self.supply_cuts = 0  # how often the supply of a board in use was cut (fault ``mag_offset_after_cut``)
        self._up_at = 0.0
        self._down_at = 0.0
        self._next_heartbeat = 0.0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._outbox: list[bytes] | None = None  # what the loop sends this turn, written once at its end
        self._after_ack: Callable[[], None] | None = None
        self._requests: queue.Queue[tuple[Callable[[], None], threading.Event]] = queue.Queue()
        self.errors: list[str] = []  # exceptions the board's thread survived (tests assert it stays empty)
        self.sent_at: float | None = None  # when the board last put bytes on the link (monotonic)
        self.frames_sent = 0  # frames put on the link
        self.frames_dropped = 0  # frames the ``drop_percent`` fault lost on the way
        self.param_reads: Counter[str] = Counter()  # PARAM_REQUEST_READ by name, per name (tests read it)
        self._answers_lost = self.faults.answers_lost()
        self.commands_heard: Counter[int] = Counter()  # COMMAND_LONG / COMMAND_INT by number (tests read it)
        self._acks_lost = self.faults.acks_lost()
        self.param_lists = 0  # PARAM_REQUEST_LIST received
        self._held_output: list[bytes] = []  # frames sent during a stall of the ``link_stalls`` fault
        self.started_at = time.monotonic()  # the ``link_stalls`` fault's stalls run from here

    # ------------------------------------------------------------------ flavour
    @abstractmethod
    def param_specs(self) -> list[ParamSpec]:
        """The firmware's parameter table (names, types, defaults)."""

    @abstractmethod
    def wire_value(self, spec: ParamSpec, value: ParamValue) -> float:
        """The float that goes into PARAM_VALUE.param_value for this autopilot."""

    @abstractmethod
    def handle_param_set(self, msg: Any) -> None:
        """PARAM_SET as this autopilot treats it (encoding, type check, storage, echo)."""

    @abstractmethod
    def load_from_storage(self, stored: dict[str, ParamValue]) -> None:
        """Boot: fill the table from storage and the detected sensors."""

    @abstractmethod
    def corrected_ut(self, sensor: SimMagnetometer, raw_ut: NDArray) -> NDArray:
        """Apply the calibration the firmware currently holds for ``sensor`` (µT in, µT out)."""

    @abstractmethod
    def stream_message(self, msg_id: int, now: float) -> Any | None:
        """The message to send for a due stream (``None`` when its sensor is absent)."""

    def extra_commands(self) -> dict[int, Callable[[list[float]], int]]:
        """Flavour-specific COMMAND_LONG handlers: ``handler(params) -> MAV_RESULT``."""
        return {}

    def tick(self, now: float) -> None:
        """Timers of the firmware (autosave, self-calibration)."""
        return None

    def on_power_loss(self) -> None:
        """Power went away: forget whatever the firmware had not finished."""
        return None

    def shutdown_ready(self, now: float) -> bool:
        """Commanded shutdown: may the board go down now (running saves finished)?"""
        return True

    def handle_other(self, msg: Any) -> None:
        """Messages the engine does not handle itself (e.g. SERIAL_CONTROL)."""
        return None

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> SimulatedAutopilot:
        self.workdir.mkdir(parents=True, exist_ok=True)
        if self.motion_source:
            from magline.sim.gimbal import MotionFollower

            self.follower = MotionFollower(self.motion_source)
        self.link = open_server(self.listen, self.usb_aliases)
        self.listen = self.link.address
        with self.lock:
            self._supply(True, time.monotonic())
            self._boot(time.monotonic(), first=True)
        self._thread = threading.Thread(target=self._run, name=f"sim-{self.flavour}", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self.follower is not None:
            self.follower.stop()
        if self._thread is not None:
            self._thread.join(timeout=5)
        if self.link is not None:
            self.link.close()

    def __enter__(self) -> SimulatedAutopilot:
        return self if self._thread is not None else self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    @property
    def address(self) -> str:
        return self.listen

    def wait_stopped(self) -> None:
        """Block until :meth:`stop` (the command-line entry point uses this)."""
        while not self._stop.wait(0.5):
            pass

    # ------------------------------------------------------------------ power (thread-safe)
    def power_off(self) -> None:
        """Cut the supply: unless USB feeds the board, link silent, RAM lost, an unfinished save lost."""
        self.supply_on = False
        if not self.usb_on:
            self._on_board_thread(self._power_off)

    def power_on(self) -> None:
        self.supply_on = True
        self._on_board_thread(self._power_on)

    def usb_power(self, on: bool) -> None:
        """The hub port's power (uhubctl): it feeds a board powered by USB; a board that is not keeps
        running on its supply (its port's node still goes and comes, as the hub re-enumerates it)."""
        if not self.usb_powered:
            self._on_board_thread(lambda: self.link.drop_peers() if not on and self.link is not None else None)
            return
        self.usb_on = on
        if on:
            self._on_board_thread(self._power_on)
        elif not self.supply_on:
            self._on_board_thread(self._power_off)

    def _on_board_thread(self, action: Callable[[], None]) -> None:
        """Run ``action`` on the board's own thread (it owns the sockets) and wait until it has run.

        Closing a socket from another thread while the board's thread waits on it in ``select``
        would break that wait; so power changes from a test or the supply simulator are queued.
        """
        if self._thread is None or threading.current_thread() is self._thread or not self._thread.is_alive():
            with self.lock:
                action()
            return
        done = threading.Event()
        self._requests.put((action, done))
        done.wait(timeout=5)

    def _power_off(self) -> None:
        self.on_power_loss()
        self._go_dark(Power.OFF)
        self._supply(False, time.monotonic())

    def _power_on(self) -> None:
        if self.power is Power.OFF:
            self.power = Power.BOOTING
            self._up_at = time.monotonic() + self.boot_time_s
            self._supply(True, time.monotonic())

    def _supply(self, on: bool, now: float) -> None:
        """The board's supply went on or off: it warms or cools (a MAVLink reboot does neither), and a
        cut moves the offset of fault ``mag_offset_after_cut``."""
        if self.warmth is not None:
            self.warmth.powered(on, now)
        if not on and self._read_since_supply:
            self.supply_cuts += 1  # a cut of a board whose compasses were read (not the supply's first "off")
        self._read_since_supply = False

    def request_reboot(self, delay_s: float) -> None:
        with self.lock:
            self.power = Power.SHUTTING_DOWN
            self._down_at = time.monotonic() + delay_s

    def _go_dark(self, state: Power) -> None:
        self.power = state
        self.link_dead = False
        self._held_output = []  # what a stall held never left the board
        self._streams.clear()
        self._parsers.clear()
        if self.link is not None:
            self.link.drop_peers()

    def _boot(self, now: float, first: bool = False) -> None:
        if self._still_by_motors:
            self._still, self._still_by_motors = None, False
        mags = list(self.magnetometers)
        if not first:
            if self.faults.mag_missing_after_reboot is not None:
                mags = [m for m in mags if m.device_id != self.faults.mag_missing_after_reboot]
            if self.faults.swap_mags_after_reboot and len(mags) > 1:
                mags[0], mags[1] = mags[1], mags[0]
        self.detected = mags
        self._held.clear()
        self.load_from_storage(self.read_storage())
        self.power = Power.UP
        self.boots += 1
        self._booted_at = now
        self._next_heartbeat = now
        if not first and self._seen_dirs and self.rest_after_cycle:
            # the station's first stream after the boot reads the proof; the second starts a new tumble
            self._rest = (least_seen_attitude(np.array(self._seen_dirs), self.field_ned), self._motion_index + 2)
        self._seen_dirs = []

    # ------------------------------------------------------------------ storage
    @property
    def storage_path(self) -> Path:
        return self.workdir / self.storage_name

    def read_storage(self) -> dict[str, ParamValue]:
        return NvStorage(self.storage_path).load()

    def write_storage(self, values: dict[str, ParamValue]) -> None:
        """Atomically replace the storage file (a real board's flash sector write)."""
        keep = {n: v for n, v in self.read_storage().items() if n in self.faults.no_persist}
        values = {n: v for n, v in values.items() if n not in self.faults.no_persist} | keep
        NvStorage(self.storage_path).save(values)

    # ------------------------------------------------------------------ inspection for tests
    def param(self, name: str) -> ParamValue:
        with self.lock:
            return self.table.values[name]

    def sensor(self, device_id: int) -> SimMagnetometer:
        return next(m for m in self.magnetometers if m.device_id == device_id)

    def corrected_sphere(self, device_id: int, n: int = 500) -> NDArray:
        """What the firmware would report for ``n`` orientations of the field, with the calibration
        it holds now (µT) — the check that a written calibration really flattens the sphere."""
        sensor = self.sensor(device_id)
        v = self.rng.normal(size=(n, 3))
        v = v / np.linalg.norm(v, axis=1, keepdims=True) * self.field_ut
        with self.lock:
            return np.array([self.corrected_ut(sensor, sensor.read_ut(b, self.rng)) for b in v])

    # ------------------------------------------------------------------ main loop
    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                self._step()
            except Exception as exc:  # a simulator that dies silently would look like a dead board
                self.errors.append(f"{type(exc).__name__}: {exc}")
                time.sleep(0.01)

    def _step(self) -> None:
        while not self._requests.empty():
            action, done = self._requests.get_nowait()
            with self.lock:
                action()
            done.set()
        up = self.power is Power.UP and not self.link_dead
        chunks = self.link.poll(self._idle_s(), up=up)
        now = time.monotonic()
        with self.lock:
            self._outbox = []
            try:
                if self.link.new_peer:
                    self.link.new_peer = False
                    self._next_heartbeat = now  # greet a new peer at once, as a board's link does
                for peer, data in chunks:
                    self._receive(peer, data)
                self._advance(now, answering=bool(chunks))
                self._release_held(now)
            finally:
                self._flush_outbox()

    def _idle_s(self) -> float:
        """How long the loop may wait for the station before the board has something to do: until its next
        message falls due and the bundle's window closes (:data:`BUNDLE_S`), at most :data:`TIMER_WAIT_S` (its other
        timers: a boot, a save, a stall's end) unless that wake would fall inside the window.

        Why not a fixed 2 ms poll: a board woke 460 times a second whatever it had to send, and a suite
        worker runs several boards beside the station on one interpreter lock (``benchmarks/sim_wakeups.py``:
        an idle board now wakes 97 times a second, its CPU about 4 % → 3 % of a core).  A message due but not
        yet sent (a shared fixture's motion not yet known at its instant) is looked at again after
        :data:`POLL_S`."""
        with self.lock:
            due = min(self._streams.next_due_s(), self._status_streams.next_due_s(),
                      self._next_heartbeat if self.power is Power.UP else math.inf,
                      self._up_at if self.power is Power.BOOTING else math.inf)
        if not self._requests.empty():
            return 0.0
        wait = due + BUNDLE_S - time.monotonic()
        if wait <= 0.0:
            return POLL_S
        # a wake for the other timers never falls inside the bundle's window: it would wake for nothing there
        return wait if wait <= TIMER_WAIT_S + BUNDLE_S else TIMER_WAIT_S

    def _receive(self, peer: object, data: bytes) -> None:
        parser = self._parsers.get(peer)
        if parser is None:
            parser = self._parsers[peer] = mavlink.MAVLink(None, srcSystem=self.system_id)
            parser.robust_parsing = True
        try:
            messages = parser.parse_buffer(data) or []
        except mavlink.MAVError:
            self.bad_frames += 1
            self._parsers.pop(peer, None)
            return
        for msg in messages:
            if msg.get_type() == "BAD_DATA":
                self.bad_frames += 1
                continue
            try:
                self._handle(msg)
            except (ValueError, KeyError, TypeError, AttributeError):
                self.bad_frames += 1  # a well-framed message with nonsense content

    def _advance(self, now: float, answering: bool = False) -> None:
        """The board's timers and streams up to ``now``; ``answering``: this turn handles what the station
        sent, so what is due leaves at once rather than after the bundle's window."""
        if self.power is Power.SHUTTING_DOWN and now >= self._down_at and self.shutdown_ready(now):
            self.on_power_loss()
            self._go_dark(Power.OFF if self.faults.reboot_fails else Power.BOOTING)
            self._up_at = now + self.boot_time_s
        if self.power is Power.BOOTING and now >= self._up_at:
            self._boot(now)
        if self.power is Power.OFF:
            return
        self.tick(now)
        if self.power is not Power.UP:
            return
        if (self.faults.link_loss_after_s is not None and self._mag_stream_started is not None
                and now - self._mag_stream_started > self.faults.link_loss_after_s and not self.link_dead):
            self.link_dead = True
            self.link.unplug()  # a network link goes silent; a USB board's node vanishes, its cable pulled
        if now >= self._next_heartbeat:
            # PX4's stream scheduler (MavlinkStream::update) keeps the 1 Hz rate on a late loop but restarts
            # from now once it is half a period late: a board that did not run sends one heartbeat, not a burst
            late = now - self._next_heartbeat
            self._next_heartbeat = now + 1.0 if late > 0.5 else self._next_heartbeat + 1.0
            self.mav.heartbeat_send(mavlink.MAV_TYPE_QUADROTOR, self.autopilot,
                                    mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 0, mavlink.MAV_STATE_STANDBY)
        if not answering and now < min(self._streams.next_due_s(), self._status_streams.next_due_s()) + BUNDLE_S:
            return  # woken by a timer inside the bundle's window: what fell due waits for the rest (BUNDLE_S)
        # each message computed and stamped at the instant it fell due, however late the host let us run —
        # and, on a shared fixture, once the board knows how the fixture moved at that instant
        horizon = self.follower.horizon(now) if self.follower is not None and self.current_motion() == "shared" \
            else now
        for instant, msg_id in self._streams.due(horizon):
            message = self.stream_message(msg_id, instant)
            if message is not None:
                self.mav.send(message)
        for instant, msg_id in self._status_streams.due(now):
            self.send_status(msg_id, instant)

    def _transmit(self, data: bytes) -> None:
        if self.power not in (Power.UP, Power.SHUTTING_DOWN) or self.link_dead or self.link is None:
            return
        if self.faults.drop_percent and self.random.random() * 100.0 < self.faults.drop_percent:
            self.frames_dropped += 1
            return
        now = time.monotonic()
        if self._stalled(now):
            self._held_output.append(data)
            return
        self._release_held(now)  # what a stall held leaves first: the order is kept
        self._send(data)
        self.frames_sent += 1
        self.sent_at = now

    def _send(self, data: bytes) -> None:
        """Into the loop's bundle when the board's own loop sends it (:data:`BUNDLE_S`), else at once."""
        if self._outbox is not None and threading.current_thread() is self._thread:
            self._outbox.append(data)
        else:
            self.link.send(data)

    def _flush_outbox(self, keep_open: bool = False) -> None:
        """What the loop sent this turn leaves in one write (UDP: datagrams of whole frames); lost when the
        board lost its power or its link meanwhile, as unsent bytes are.  ``keep_open``: the turn goes on
        bundling what it sends next (an ACK flushed before the action it announces)."""
        frames, self._outbox = self._outbox, ([] if keep_open and self._outbox is not None else None)
        if not frames or self.power not in (Power.UP, Power.SHUTTING_DOWN) or self.link_dead or self.link is None:
            return
        largest = {"stream": math.inf, "datagram": UDP_BUNDLE_BYTES, "frame": 0}[self.link.bundling]
        bundle = b""
        for frame in frames:
            if bundle and len(bundle) + len(frame) > largest:
                self.link.send(bundle)
                bundle = b""
            bundle += frame
        self.link.send(bundle)

    def _stalled(self, now: float) -> bool:
        """Within a stall of the ``link_stalls`` fault (from the board's start)."""
        stalls = self.faults.stalls()
        return stalls is not None and (now - self.started_at) % stalls[1] < stalls[0]

    def _release_held(self, now: float) -> None:
        """A stall over: what the board sent meanwhile leaves at once, in order."""
        if not self._held_output or self._stalled(now) or self.link is None or self.link_dead:
            return
        held, self._held_output = self._held_output, []
        for data in held:
            self._send(data)
            self.frames_sent += 1
        self.sent_at = now

    def health(self) -> str:
        """The board's side of a lost link, in one line: a test that sees the station lose the link
        says whether the simulator stopped talking, and why, or kept talking to a station that did not
        hear it."""
        now = time.monotonic()
        silent = "never sent" if self.sent_at is None else f"last sent {now - self.sent_at:.1f} s ago"
        alive = self._thread is not None and self._thread.is_alive()
        peers = len(getattr(self.link, "clients", getattr(self.link, "peers", ())) or ())
        return (f"simulator: power {self.power.name}, thread {'alive' if alive else 'dead'}, {silent}, "
                f"{peers} peer(s), link_dead={self.link_dead}, errors {self.errors[-3:]}")

    # ------------------------------------------------------------------ helpers for flavours
    def time_boot_ms(self, now: float) -> int:
        return int((now - self._booted_at) * 1000) & 0xFFFFFFFF

    def time_boot_us(self, now: float) -> int:
        return int((now - self._booted_at) * 1e6)

    def current_motion(self) -> str:
        return self.motions[min(max(self._motion_index, 0), len(self.motions) - 1)]

    # After a power cycle the unit lies still where the tumble showed the field least (issue 50): the
    # verify phase reads the firmware's calibrated output in an attitude the fit saw little of, as on a
    # line where the unit is set down whichever way it came to rest.  It is picked up again when the
    # station starts its next tumble (its second stream after the boot; the first is the proof's read)
    # — not after a time, which a slow machine's verify outlasted and a fast re-test started inside,
    # tumbling from a still attitude that jumped to the spiral.
    rest_after_cycle = True

    @property
    def resting(self) -> Rotation | None:
        """The attitude the unit rests in after the last power cycle, while it rests."""
        return self._rest[0] if self._rest is not None and self._motion_index < self._rest[1] else None

    def attitude_at(self, now: float) -> Rotation:
        if self._still is not None:
            held, since = self._still
            drift = self.faults.moved_during_sweep  # °/s: a unit knocked or slipping in its fixture
            return held * Rotation.from_euler("Z", drift * max(now - since, 0.0), degrees=True) if drift else held
        if self._rest is not None and self._motion_index < self._rest[1] and self.field_provider is None:
            return self._rest[0]
        motion = self.current_motion()
        if motion == "shared" and self.follower is not None:
            return self.follower.attitude(now)
        # one instant is asked for again by every compass read at it, and by its IMU fields
        key = (motion, now - self._t0, self.speed)
        if self._attitude_memo is None or self._attitude_memo[0] != key:
            self._attitude_memo = (key, attitude(motion, now - self._t0, self.speed, self.field_ned))
        return self._attitude_memo[1]

    def motion_speed(self) -> float:
        """How much faster than a real tumble the unit turns (the gimbal's speed when it follows one)."""
        if self.follower is not None and self.current_motion() == "shared":
            return self.follower.speed
        return self.speed

    # The firmware's timing of its magnetometer against its accelerometer (issue 50): how old a new
    # magnetometer reading is when it first appears in a message, and how old the message's
    # accelerometer reading is — both against the message's time stamp, in seconds of a real tumble.
    # A motion sped up for a test compresses them with it (divided by its speed), so a skew turns the
    # unit by the angle it does on a real tumble; a slowed motion keeps the firmware's own milliseconds.
    def mag_age_s(self) -> float:
        return 0.0

    def accel_age_s(self) -> float:
        return 0.0

    def _real_time(self, seconds: float) -> float:
        return seconds / max(1.0, self.motion_speed())

    def body_field_ut(self, now: float) -> NDArray:
        if self.field_provider is not None:
            return np.asarray(self.field_provider(), float)
        return self.ned_to_body(now) @ self.field_ned

    def accel_mg(self, now: float) -> NDArray:
        """Gravity in the body frame (mG), for the IMU fields of the streamed messages."""
        return self.ned_to_body(now - self._real_time(self.accel_age_s())) @ np.array([0.0, 0.0, -1000.0])

    def ned_to_body(self, now: float) -> NDArray:
        """The matrix turning an NED vector into the body at ``now``: the attitude's transpose.  Why a
        matrix and not ``attitude.inv().apply``: a board turns two vectors at every message it streams, and
        scipy's inverse and apply cost 50 µs each where this costs 5 (with the sensor's own turn kept as a
        matrix, a streamed message takes 440 µs instead of 666: ``benchmarks/sim_wakeups.py``)."""
        if self._still is not None or (self._rest is not None and self._motion_index < self._rest[1]):
            return self.attitude_at(now).as_matrix().T  # held or resting: one attitude, its branches as they are
        motion = self.current_motion()
        if motion == "shared":
            if self.follower is None:
                return self.attitude_at(now).as_matrix().T
            return self.follower.matrix(now).T  # as attitude_at would compose it, without scipy's overhead
        # one instant is asked for again by every compass read at it, and by its IMU fields
        key = (motion, now - self._t0, self.speed)
        if self._matrix_memo is None or self._matrix_memo[0] != key:
            self._matrix_memo = (key, ned_to_body(motion, now - self._t0, self.speed, self.field_ned))
        return self._matrix_memo[1]

    def sensor_rate_hz(self, sensor: SimMagnetometer) -> float:
        return self.mag_rate_hz or self.firmware_mag_rate_hz or driver_rate_hz(sensor.device_id)

    def samples_per_reading(self, sensor: SimMagnetometer) -> int:
        """How many of the driver's samples one published reading averages: one — the firmware publishes
        each sample as it comes (PX4's sensor_mag, INAV's compass task reading its sensor once)."""
        return 1

    # ------------------------------------------------------------------ current and its interference
    def hold_still(self, still: bool) -> None:
        """The unit is clamped in its fixture (a load or the motors connected): it keeps the attitude it
        has now until released — what the operator does when the station asks for the current sweep."""
        with self.lock:
            now = time.monotonic()
            self._still = (self.attitude_at(now), now) if still and self._still is None else (
                self._still if still else None)

    # Motor current against throttle, one motor spinning (ArduCopter SITL, docs/firmware.md, *Current
    # interference*): 0 / 0.44 / 3.1 / 5.0 / 9.9 / 18 A at 0 / 20 / 40 / 50 / 70 / 100 %
    MOTOR_CURVE = ((0.0, 0.0), (20.0, 0.44), (40.0, 3.1), (50.0, 5.0), (70.0, 9.9), (100.0, 18.0))

    def true_current_a(self, now: float) -> float:
        """The current through the board's power path (A): its own draw, the load's, a spinning motor's."""
        if self.power is not Power.UP:
            return 0.0
        load = float(self.current_provider()) if self.current_provider is not None else 0.0
        motor = 0.0
        if self._motor_test is not None:
            throttle, until = self._motor_test
            if now < until:
                motor = float(np.interp(throttle, *zip(*self.MOTOR_CURVE, strict=True)))
            else:
                self._motor_test = None
        current = self.idle_current_a + max(load, 0.0) + motor
        self._peak_current_a = max(self._peak_current_a, current)
        return current

    def firmware_current_a(self, now: float | None = None) -> float:
        """What the board's own current sensor reports (its scale error applied) — 0 where it has none
        (fault ``current_sensor=none``: nothing to compensate with), its own draw alone where the sweep's
        current bypasses the monitor the firmware reads (``current_sensor=bypassed``)."""
        sensor = self.faults.current_sensor
        if sensor == "none":
            return 0.0
        if sensor == "bypassed":  # the compasses still see the whole current (interference_ut)
            return self.idle_current_a * self.current_scale if self.power is Power.UP else 0.0
        return self.true_current_a(time.monotonic() if now is None else now) * self.current_scale

    # BATTERY_STATUS / SYS_STATUS current_battery (cA) of a battery monitor that measures no current:
    # MAVLink's "not measured" −1 (ArduPilot); PX4 sends its battery's current_a of −1 A × 100
    CURRENT_NOT_MEASURED_CA = -1

    def corrected_change_ut(self, index: int, amps: float, body_ut: NDArray | None = None) -> NDArray:
        """How far the firmware's corrected output of compass ``index`` moves (µT) when ``amps`` flow, for
        one field and without noise: what its current compensation leaves of the interference — the
        simulator's truth, for tests and benchmarks to hold a measured figure against."""
        sensor = self.magnetometers[index]
        body = np.array([20.0, 5.0, 40.0]) if body_ut is None else np.asarray(body_ut, float)
        noise, sensor.truth.noise_ut = sensor.truth.noise_ut, 0.0
        provider = self.current_provider
        rng = np.random.default_rng(0)
        out = []
        try:
            for current in (0.0, amps):
                self.current_provider = lambda current=current: current
                raw = sensor.read_ut(body + current * sensor.interference_ut_per_a, rng)
                out.append(self.corrected_ut(sensor, raw))
        finally:
            sensor.truth.noise_ut, self.current_provider = noise, provider
        return out[1] - out[0]

    def interference_ut(self, sensor: SimMagnetometer, now: float) -> NDArray:
        """The field the power wiring's current adds at this compass (body axes, µT): its own vector per
        amp, and — fault ``interference_remanence`` — a part magnetised by the largest current so far."""
        current = self.true_current_a(now)
        field = current * sensor.interference_ut_per_a
        remanence = self.faults.interference_remanence
        if remanence and self._peak_current_a > 1.0:  # magnetised once an amp or more has flowed
            field = field + remanence * sensor.interference_ut_per_a / max(np.linalg.norm(sensor.interference_ut_per_a),
                                                                             1e-9)
        return field

    def held_reading_ut(self, sensor: SimMagnetometer, now: float) -> NDArray:
        """The sensor's latest reading: a new one every 1/rate s, held in between (sample and hold).

        Why: a MAVLink stream is sent at the rate asked for, whatever the sensor's own rate, so a
        stream faster than the sensor repeats each reading — exactly, on every axis."""
        period = 1.0 / self.sensor_rate_hz(sensor)
        due, reading = self._held.get(sensor.device_id, (now, None))
        if reading is None or now >= due:
            taken = now - self._real_time(self.mag_age_s() + self._latency_s.get(sensor.device_id, 0.0))
            count = self.samples_per_reading(sensor)
            # the driver's samples averaged into this reading, spread over its period and centred on ``taken``
            times = [taken + self._real_time((j - (count - 1) / 2.0) * period / count) for j in range(count)]
            fields = np.array([self.body_field_ut(t) + self.interference_ut(sensor, t) for t in times])
            field = fields.mean(axis=0)
            if len(self._seen_dirs) < 20000:
                self._seen_dirs.append(field / np.linalg.norm(field))
            self._read_since_supply = True
            # fault quiet_at_rest, held for a current sweep: no noise (ArduCopter's SITL compass), so the reading
            # changes only with the current's field and is the same in every message in between
            quiet_held = self.faults.quiet_at_rest and self._still is not None
            samples = sensor.read_samples_ut(fields, self.rng, noiseless=quiet_held)
            reading = (samples.mean(axis=0) + self.warmup_offset_ut(now)
                       + self.WARMUP_DIRECTION * self.faults.mag_offset_after_cut * self.supply_cuts)
            stuck_after = self.faults.mag_stuck_after_s
            if (stuck_after is not None and self._mag_stream_started is not None
                    and now - self._mag_stream_started > stuck_after) or sensor.device_id in self._stuck:
                reading = self._stuck.setdefault(sensor.device_id, reading)
            if self.faults.quiet_at_rest and self.resting is not None:  # the first reading at rest, ever after
                reading = self._quiet.setdefault(sensor.device_id, reading)
            else:
                self._quiet.pop(sensor.device_id, None)
            due = due + period if now - due < period else now + period
            self._held[sensor.device_id] = (due, reading)
        return reading

    # the direction in which a warming board's compass offsets move (fault ``mag_warmup``)
    WARMUP_DIRECTION = np.array([0.64, -0.48, 0.6]) / np.linalg.norm([0.64, -0.48, 0.6])

    def warmup_offset_ut(self, now: float) -> NDArray:
        """How far the compasses' offset still is from its settled value ``now``: the fault's size
        times how far the board is from its operating temperature (:class:`BoardWarmth`)."""
        warmup = self.faults.warmup()
        if warmup is None or self.warmth is None:
            return np.zeros(3)
        return self.WARMUP_DIRECTION * warmup[0] * (1.0 - self.warmth.at(now))

    def raw_reading_ut(self, index: int, now: float) -> tuple[SimMagnetometer, NDArray] | None:
        if index >= len(self.detected):
            return None
        sensor = self.detected[index]
        return sensor, self.held_reading_ut(sensor, now)

    # The index a PARAM_VALUE carries: PX4 its parameter's own; ArduPilot the index it was asked by (a read
    # by name, and the echo of a set, carry -1, sent as 65535: GCS_Param.cpp ``reply.param_index =
    # req.param_index``), its own only in a list it streams
    ANSWERS_WITH_ASKED_INDEX = False

    @functools.cached_property
    def listed(self) -> list[str]:
        """The names this firmware has, in its index order (the ``unknown_params`` fault's are not in it):
        fixed from the board's creation, so worked out once, not at every answer."""
        unknown = set(self.faults.unknown_params)
        return [name for name in self.table.names if name not in unknown]

    @functools.cached_property
    def _listed_index(self) -> dict[str, int]:
        """Each listed name's index: a list streamed whole asked ``list.index`` once per name, n² in all."""
        return {name: index for index, name in enumerate(self.listed)}

    def send_param(self, name: str, asked_index: int | None = None) -> None:
        spec = self.table.specs[name]
        listed = self.listed
        index = self._listed_index[name]
        if self.ANSWERS_WITH_ASKED_INDEX and asked_index is not None:
            index = asked_index & 0xFFFF
        self.mav.param_value_send(name.encode(), self.wire_value(spec, self.table.values[name]), spec.type,
                                  len(listed), index)

    def statustext(self, severity: int, text: str) -> None:
        self.mav.statustext_send(severity, text.encode()[:50])

    def _for_us(self, msg: Any) -> bool:
        return getattr(msg, "target_system", 0) in (0, self.system_id)

    # ------------------------------------------------------------------ message handling
    def _handle(self, msg: Any) -> None:
        kind = msg.get_type()
        if kind == "HEARTBEAT":
            return
        if not self._for_us(msg):
            return
        if kind == "PARAM_REQUEST_LIST":
            self.param_lists += 1
            for name in self.listed:
                self.send_param(name)
        elif kind == "PARAM_REQUEST_READ":
            listed = self.listed
            name = msg.param_id if msg.param_index < 0 else (
                listed[msg.param_index] if msg.param_index < len(listed) else None)
            if msg.param_index < 0:
                self.param_reads[name] += 1
            if self.param_reads[name] <= self._answers_lost.get(name, 0) and msg.param_index < 0:
                return
            if name in self.table and name not in self.faults.unknown_params:
                self.send_param(name, msg.param_index)
        elif kind == "PARAM_SET":
            if msg.param_id == self.faults.link_loss_at_param_set:
                self.link_dead = True
                return
            if msg.param_id not in self.faults.unknown_params:
                self.handle_param_set(msg)
        elif kind in ("COMMAND_LONG", "COMMAND_INT"):
            params = ([msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7]
                      if kind == "COMMAND_LONG" else
                      [msg.param1, msg.param2, msg.param3, msg.param4, float(msg.x), float(msg.y), msg.z])
            self._command(msg, msg.command, params)
        else:
            self.handle_other(msg)

    def _command(self, msg: Any, command: int, params: list[float]) -> None:
        handlers: dict[int, Callable[[list[float]], int]] = {
            mavlink.MAV_CMD_SET_MESSAGE_INTERVAL: self._set_message_interval,
            mavlink.MAV_CMD_REQUEST_MESSAGE: self._request_message,
            mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: self._request_capabilities,
            mavlink.MAV_CMD_DO_MOTOR_TEST: self._motor_test_command,
            **self.extra_commands(),
        }
        handler = handlers.get(command)
        result = handler(params) if handler else UNSUPPORTED
        self.commands_heard[command] += 1
        lost = self.commands_heard[command] <= self._acks_lost.get(command, 0)
        if not lost and not (self.faults.lose_reboot_ack and command == mavlink.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN):
            self.mav.command_ack_send(command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent())
        self._act_after_answer()

    def _motor_test_command(self, params: list[float]) -> int:
        """MAV_CMD_DO_MOTOR_TEST, throttle in percent (param2 = 0): one motor spins at param3 % for param4
        seconds, drawing the current of :attr:`MOTOR_CURVE` through the board's sensor (ArduCopter spins the
        next motor after a pause when param5 asks for more; one is enough for the current).  Refused with
        the fault ``motor_test_refused`` (RC not calibrated, a safety switch on)."""
        if self.faults.motor_test_refused:
            if self.MOTOR_TEST_REFUSAL:  # the firmware's own why, on the link that asked, after the ACK
                self.after_ack(lambda: self.statustext(mavlink.MAV_SEVERITY_CRITICAL, self.MOTOR_TEST_REFUSAL))
            return DENIED
        if int(params[1]) != 0 or not 0.0 <= params[2] <= 100.0 or params[3] < 0:
            return DENIED
        # 0 %: the motor stops (a test at zero throttle ends the running one)
        self._motor_test = (float(params[2]), time.monotonic() + float(params[3])) if params[2] > 0 else None
        # a motor test runs with the unit strapped in its cradle: it keeps its attitude from the first command
        # until a tumble starts again (a stream after the motors were quiet a while) or it boots
        self._motors_commanded_at = time.monotonic()
        if self._still is None:
            self._still = (self.attitude_at(self._motors_commanded_at), self._motors_commanded_at)
            self._still_by_motors = True
        return ACCEPTED

    def after_ack(self, action: Callable[[], None]) -> None:
        """Run ``action`` once the current command's ACK is sent (ACK first, then act)."""
        self._after_ack = action

    def _act_after_answer(self) -> None:
        """The action an answer announced (:meth:`after_ack`), once the answer has left: flushed ahead of the
        rest of the turn's bundle, since the action may cut the power."""
        after, self._after_ack = self._after_ack, None
        if after is not None:
            self._flush_outbox(keep_open=True)
            after()

    STATUS_MESSAGES = (mavlink.MAVLINK_MSG_ID_BATTERY_STATUS, mavlink.MAVLINK_MSG_ID_SYS_STATUS)
    MOTOR_TEST_REFUSAL = ""  # the STATUSTEXT a firmware says a refused motor test's cause in (ArduCopter's)

    def send_status(self, msg_id: int, now: float) -> None:
        """BATTERY_STATUS (battery 0, the primary monitor) and SYS_STATUS with the board's measured
        current, in the messages' centi-amps as both firmwares send it."""
        measured = self.faults.current_sensor != "none"
        centi = round(self.firmware_current_a(now) * 100.0) if measured else self.CURRENT_NOT_MEASURED_CA
        if msg_id == mavlink.MAVLINK_MSG_ID_BATTERY_STATUS:
            self.mav.battery_status_send(0, mavlink.MAV_BATTERY_FUNCTION_ALL, mavlink.MAV_BATTERY_TYPE_LIPO, 2500,
                                         [16800, 65535, 65535, 65535, 65535, 65535, 65535, 65535, 65535, 65535],
                                         centi, -1, -1, 80)
        else:
            sensors = mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG | mavlink.MAV_SYS_STATUS_SENSOR_BATTERY
            self.mav.sys_status_send(sensors, sensors, sensors, 100, 16800, centi, 80, 0, 0, 0, 0, 0, 0)

    def _set_message_interval(self, params: list[float]) -> int:
        msg_id, interval_us = int(params[0]), params[1]
        if msg_id in self.STATUS_MESSAGES:
            if interval_us <= 0:
                self._status_streams.stop(msg_id)
            else:
                self._status_streams.start(msg_id, max(interval_us / 1e6, 1.0 / MAX_STREAM_HZ), time.monotonic())
            return ACCEPTED
        if msg_id not in self.stream_sensor and msg_id != mavlink.MAVLINK_MSG_ID_HEARTBEAT:
            return FAILED
        if msg_id == mavlink.MAVLINK_MSG_ID_HEARTBEAT:
            return ACCEPTED
        if interval_us < 0 or interval_us == 0:
            self._streams.stop(msg_id)
        else:
            interval = max(interval_us / 1e6, 1.0 / MAX_STREAM_HZ)
            if not self._streams:
                self._motion_index += 1  # the operator starts (another) tumble
                if self._still_by_motors and time.monotonic() - self._motors_commanded_at > MOTOR_CRADLE_S:
                    self._still, self._still_by_motors = None, False  # out of the cradle
                self._mag_stream_started = time.monotonic()
            self._streams.start(msg_id, interval, time.monotonic())
        if not self._streams:
            self._mag_stream_started = None
        return ACCEPTED

    def _request_message(self, params: list[float]) -> int:
        msg_id = int(params[0])
        if msg_id == mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            self.after_ack(self._send_version)
            return ACCEPTED
        if msg_id == mavlink.MAVLINK_MSG_ID_SYSTEM_TIME:
            self.after_ack(lambda: self.mav.system_time_send(int(time.time() * 1e6),
                                                             self.time_boot_ms(time.monotonic())))
            return ACCEPTED
        if msg_id in self.stream_sensor:
            self.after_ack(lambda: self._send_once(msg_id))
            return ACCEPTED
        return UNSUPPORTED

    def _request_capabilities(self, params: list[float]) -> int:
        if int(params[0]) != 1:
            return ACCEPTED
        self.after_ack(self._send_version)
        return ACCEPTED

    def _send_once(self, msg_id: int) -> None:
        message = self.stream_message(msg_id, time.monotonic())
        if message is not None:
            self.mav.send(message)

    firmware_version: tuple[int, int, int] = (1, 0, 0)

    def _send_version(self) -> None:
        major, minor, patch = getattr(self, "reported_version", self.firmware_version)
        sw = (major << 24) | (minor << 16) | (patch << 8) | mavlink.FIRMWARE_VERSION_TYPE_OFFICIAL
        self.mav.autopilot_version_send(self.capabilities, sw, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8,
                                        0x1209, 0x5741, self.uid)
