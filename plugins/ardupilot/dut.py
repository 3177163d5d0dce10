"""The ArduPilot DUT backend: calibrate every compass through pymavlink, persist, prove it survived.

Sequence as the core's phases drive it: connect (heartbeat, version, compass ids, orientations) →
prepare (COMPASS_LEARN off, read the calibration each set holds now) → samples (RAW_IMU /
SCALED_IMU2/3, one per compass set, in one stream; each compass's repeats dropped and the firmware's
correction inverted on its own; gravity from RAW_IMU's accelerometer, since SCALED_IMU3's is empty
on SITL) → parameters (OFS/DIA/ODI/SCALE of the set whose DEV_ID is the sensor, checked against
ArduPilot's limits; COMPASS_ORIENTn where the mounting check fixes one) → commit (force-save the
device ids) → reboot and reconnect → read back, every compass still there, prearm check (an
uncalibrated or inconsistent compass is reported there) → restore COMPASS_LEARN.
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Iterator
from typing import TYPE_CHECKING

import numpy as np

from magline.plugin import (
    INT16_MG_RANGE_UT,
    NOTHING_LISTENS_S,
    DutError,
    LinkError,
    Magnetometer,
    NotRestored,
    ParamValue,
    ReadingsAtRest,
    SensorStreams,
    StationFault,
    UnansweredRequest,
    UnitInfo,
    await_new_boot,
    mavlink2_frame_bytes,
    require_same_vehicle,
    untruncate_mg,
)
from magline.plugins.ardupilot.calibration import (
    SETS,
    HeldCalibration,
    check_firmware_limits,
    fit_to_params,
    rename_for_set,
    set_names,
)
from magline.plugins.ardupilot.link import ML, RESULT_NAMES, ArduPilotLink, NotKnown

if TYPE_CHECKING:
    from magline.plugin import FitResult, Product, SampleChunk
    from magline.plugins.ardupilot.options import ArduPilotOptions

log = logging.getLogger(__name__)

# compass priority 0 / 1 / 2 (= set 1 / 2 / 3 after the boot-time reorder) streams in these messages
STREAMS = (("RAW_IMU", ML.MAVLINK_MSG_ID_RAW_IMU), ("SCALED_IMU2", ML.MAVLINK_MSG_ID_SCALED_IMU2),
           ("SCALED_IMU3", ML.MAVLINK_MSG_ID_SCALED_IMU3))
INT_PARAMS = ("COMPASS_DEV_ID", "COMPASS_PRIO", "COMPASS_LEARN", "COMPASS_OFFS_MAX", "COMPASS_MOTCT",
              "COMPASS_ORIENT", "COMPASS_EXTERN")

CHUNK = 10
CHUNK_WITHIN_S = 0.25  # a slow compass's readings handed on at least this often
BATTERY_RATE_HZ = 10.0  # BATTERY_STATUS during a current sweep
COMPASS_HZ = 10.0  # ArduCopter reads its compasses at about 10 Hz, whatever the stream rate
DRIVER_SAMPLE_HZ = 100.0  # how often a compass driver samples (AP_Compass_SITL, IST8310 and most others: 100 Hz)
MOT_RANGE_MG_PER_A = 1000.0  # COMPASS_MOTn_* @Range
RESTORE_RECONNECT_S = 3.0  # a vehicle that does not answer by then is reported as not restored
COMPASS_PREARM = "PreArm: Compass"
MOTOR_TEST_WHY_S = 1.0  # how long a refused motor test's STATUSTEXT is waited for (it follows the ACK)


def _firmware(version: int) -> str:
    return f"{version >> 24 & 0xFF}.{version >> 16 & 0xFF}.{version >> 8 & 0xFF}"


class ArduPilotDut:
    def __init__(self, product: Product, options: ArduPilotOptions) -> None:
        self.product = product
        self.opts = options
        self.link = ArduPilotLink(product.connection, param_timeout_s=options.param_timeout_s)
        self.device_id = 0  # the primary compass being calibrated
        self.ids: dict[str, int] = {}  # set suffix → device id, as the unit has them now
        self.written_sets: dict[int, str] = {}  # device id → set suffix when its calibration was written
        self.chosen: list[int] = []  # the compasses this run calibrates, primary first
        self.offs_max_mg = 1800.0
        self.held: dict[int, HeldCalibration] = {}
        self.magnetometers: list[Magnetometer] = []
        self._saved_learn: int | None = None
        self._saved_motct: int | None = None  # COMPASS_MOTCT switched off for the current sweep
        self.stream_current = False  # the sweep asked for the unit's battery current with the readings
        self.system_id = 0  # the unit's MAVLink system id: another one answering later is another vehicle
        self.uid = 0  # the board's hardware UID (AUTOPILOT_VERSION), compared after the power cycle

    # ------------------------------------------------------------------ link
    def connect(self) -> UnitInfo:
        heartbeat = self.link.open(self.opts.connect_timeout_s, NOTHING_LISTENS_S)
        if heartbeat.autopilot != ML.MAV_AUTOPILOT_ARDUPILOTMEGA:
            self.link.close()
            raise StationFault(f"the vehicle on {self.product.connection} is not ArduPilot "
                           f"(MAV_AUTOPILOT {heartbeat.autopilot}); check the product's backend")
        self.system_id = self.link.target_system
        version = self.link.request_message(ML.MAVLINK_MSG_ID_AUTOPILOT_VERSION, "AUTOPILOT_VERSION")
        firmware = _firmware(version.flight_sw_version) if version is not None else "unknown"
        self.uid = int(version.uid) if version is not None else 0  # the board's hardware UID (0: not said)
        self._read_ids()
        self.device_id = self._selected_id()
        self.chosen = [self.device_id]
        self.written_sets = {}
        self._prearm_since: float | None = None  # when the arming checks were asked for after a power cycle
        self._lacks: dict[str, str | None] = {}  # name → why this firmware lacks it (None: it has it), asked once
        self.offs_max_mg = self.link.get("COMPASS_OFFS_MAX")
        self.magnetometers = [self._magnetometer(suffix, dev) for suffix, dev in self.ids.items() if dev]
        return UnitInfo(autopilot="ArduPilot", firmware=firmware, sensors=[i for i in self.ids.values() if i],
                        selected_sensor=self.device_id, soft_iron_model="full",
                        extra={"compass_set": SETS.index(self.suffix) + 1,
                               "capabilities": int(version.capabilities) if version is not None else 0},
                        magnetometers=self.magnetometers)

    def _magnetometer(self, suffix: str, device_id: int) -> Magnetometer:
        """A compass as the firmware holds it: COMPASS_ORIENTn turns an external compass's readings into
        the body before anything else (so the streamed field is in body axes); an internal compass
        ignores it — its fix is COMPASS_EXTERNn = 1 together with the orientation (docs/firmware.md,
        *What the firmware applies*).  Each reading is the mean of the driver's samples since the vehicle
        last read the compass (``drain_accumulated_samples``, ArduCopter reads at 10 Hz)."""
        names = set_names(suffix)
        external = int(self.link.get(names["EXTERN"][0])) != 0
        orient = int(self.link.get(names["ORIENT"][0])) if external else 0
        return Magnetometer(device_id=device_id, label=f"compass {SETS.index(suffix) + 1}", external=external,
                            orientation=orient, readings_rotated=True,
                            fix_params=names["ORIENT"] + ([] if external else names["EXTERN"]),
                            range_ut=INT16_MG_RANGE_UT, averaged_sample_hz=DRIVER_SAMPLE_HZ)

    def use_magnetometers(self, device_ids: list[int]) -> None:
        self.chosen = list(device_ids)

    @property
    def suffix(self) -> str:
        """The primary compass's set now (sets move with COMPASS_PRIOn_ID at boot)."""
        return self._suffix_of(self.device_id)

    def _read_ids(self) -> None:
        self.ids = {s: int(self.link.get(f"COMPASS_DEV_ID{s}")) for s in SETS}

    def _selected_id(self) -> int:
        present = [i for i in self.ids.values() if i]
        wanted = self.product.magnetometer
        if wanted == "primary":
            if not self.ids[""]:
                raise DutError("the unit reports no primary compass (COMPASS_DEV_ID = 0)")
            return self.ids[""]
        if not isinstance(wanted, int) and not str(wanted).isdigit():
            raise DutError(f"magnetometer {wanted!r}: give a device id or 'primary'")
        wanted = int(wanted)
        if wanted not in present:
            have = ", ".join(map(str, present)) or "none"
            raise DutError(f"magnetometer {wanted} is not on this unit; it has {have}")
        return wanted

    def _suffix_of(self, device_id: int) -> str:
        """The set whose DEV_ID is the sensor — never a position (sets move with COMPASS_PRIOn_ID)."""
        return next(s for s, i in self.ids.items() if i == device_id)

    def close(self) -> None:
        self.link.close()

    @property
    def boot_timeout_s(self) -> float:
        """How long the station waits for the new boot after a power cycle (the operator's countdown)."""
        return self.opts.boot_timeout_s

    # ------------------------------------------------------------------ prepare / restore
    def prepare(self) -> None:
        learn = int(self.link.get("COMPASS_LEARN"))
        if learn != 0:
            self.link.set("COMPASS_LEARN", 0)  # the firmware must not learn offsets during the test
            self._saved_learn = learn
        self._read_held()

    def _read_held(self) -> None:
        """The calibration each chosen compass holds now: what the stream is undone with."""
        self.held = {}
        for device_id in self.chosen:
            suffix = self._suffix_of(device_id)
            names = [n for key in ("OFS", "DIA", "ODI", "SCALE") for n in set_names(suffix)[key]]
            self.held[device_id] = HeldCalibration.from_params({n: self.link.get(n) for n in names}, suffix)

    def restore(self) -> None:
        """COMPASS_LEARN (and COMPASS_MOTCT, switched off for a current sweep and not written since) back
        to what they were (ArduPilot stores every PARAM_SET at once, so the change is in storage either
        way); after a closed link, one short reconnect is tried first."""
        saved = {name: value for name, value in (("COMPASS_LEARN", self._saved_learn),
                                                 ("COMPASS_MOTCT", self._saved_motct)) if value is not None}
        self.stream_current = False
        if not saved:
            return
        try:
            if self.link.conn is None:
                self.link.open(min(self.opts.connect_timeout_s, RESTORE_RECONNECT_S))
            for name, value in saved.items():
                self.link.set(name, value)
        except DutError as exc:
            raise NotRestored(str(exc), {name: f"0 (was {value})" for name, value in saved.items()}) from exc
        self._saved_learn = self._saved_motct = None

    # ------------------------------------------------------------------ data
    def samples(self, rate_hz: float) -> Iterator[SampleChunk]:
        """Every chosen compass's set stream at once, plus RAW_IMU for gravity (SITL's SCALED_IMU3
        carries no accelerometer); each compass's repeats are dropped on their own."""
        if not self.held:
            raise DutError("prepare() must run before acquisition")
        by_kind = {STREAMS[SETS.index(self._suffix_of(d))][0]: d for d in self.chosen}
        kinds = list(dict.fromkeys(["RAW_IMU", *by_kind]))
        ids = {kind: msg_id for kind, msg_id in STREAMS}
        if self.link.port is not None:
            battery = {"BATTERY_STATUS": (mavlink2_frame_bytes(ML.MAVLINK_MSG_ID_BATTERY_STATUS), BATTERY_RATE_HZ)}
            self.link.port.require_capacity({k: (mavlink2_frame_bytes(ids[k]), rate_hz) for k in kinds},
                                            battery if self.stream_current else None)
        self.link.drain()
        for kind in kinds:
            self.link.set_message_interval(ids[kind], rate_hz)
        streams = SensorStreams(self.device_id, self.chosen, lambda d, mg: self.held[d].raw_ut(mg))
        wanted = [*kinds, "BATTERY_STATUS"] if self.stream_current else kinds
        if self.stream_current:  # the primary battery monitor's current: what COMPASS_MOTCT = 2 multiplies by
            self.link.set_message_interval(ML.MAVLINK_MSG_ID_BATTERY_STATUS, BATTERY_RATE_HZ)
        try:
            while True:
                msg = self.link.recv(wanted, self.opts.stream_timeout_s)
                if msg is None:
                    self.link.require_alive(f"link lost during acquisition: no {'/'.join(kinds)} for "
                                            f"{self.opts.stream_timeout_s:g} s")
                    raise DutError(f"the vehicle answers but sent no {'/'.join(kinds)} for "
                                   f"{self.opts.stream_timeout_s:g} s: compass {self.device_id} delivers no readings")
                kind = msg.get_type()
                if kind == "BATTERY_STATUS":
                    if msg.id == 0:
                        streams.current(msg.current_battery)
                    continue
                t_ms = msg.time_usec / 1000.0 if kind == "RAW_IMU" else float(msg.time_boot_ms)
                if kind == "RAW_IMU":
                    streams.accel(t_ms, msg.xacc, msg.yacc, msg.zacc)
                if kind in by_kind:  # the stream is faster than the compass: repeats are dropped
                    streams.mag(by_kind[kind], t_ms, msg.xmag, msg.ymag, msg.zmag)
                if streams.ready(CHUNK, CHUNK_WITHIN_S):
                    yield streams.take()
        finally:
            for kind in kinds:
                with contextlib.suppress(DutError):  # when the link is gone the stream stops with it
                    self.link.set_message_interval(ids[kind], 0)
            if self.stream_current:
                with contextlib.suppress(DutError):
                    self.link.set_message_interval(ML.MAVLINK_MSG_ID_BATTERY_STATUS, 0)

    # ------------------------------------------------------------------ parameters
    def calibration_params(self, fit: FitResult, sensor: int | None = None) -> dict[str, ParamValue]:
        device_id = self.device_id if sensor is None else sensor
        suffix = self._suffix_of(device_id)
        params = fit_to_params(fit, suffix)
        check_firmware_limits(params, suffix, self.offs_max_mg)
        self.written_sets[device_id] = suffix
        return dict(params)

    def orientation_params(self, device_id: int, value: int) -> dict[str, ParamValue]:
        """COMPASS_ORIENTn = the mounting found; an internal compass ignores it unless marked external."""
        sensor = next(m for m in self.magnetometers if m.device_id == device_id)
        suffix = self._suffix_of(device_id)
        self.written_sets[device_id] = suffix
        names = set_names(suffix)
        return {names["ORIENT"][0]: int(value), **({} if sensor.external else {names["EXTERN"][0]: 1})}

    def read_params(self, names: list[str]) -> dict[str, ParamValue]:
        """By the names written: a set that moved at boot (priorities) is read where it is now."""
        out: dict[str, ParamValue] = {}
        for name in names:
            value = self.link.get(self._where_now(name))
            out[name] = int(value) if name.startswith(INT_PARAMS) else value
        return out

    def _where_now(self, name: str) -> str:
        for device_id, suffix in self.written_sets.items():
            written = {n for group in set_names(suffix).values() for n in group}
            if name in written and device_id in self.ids.values():
                return rename_for_set(name, suffix, self._suffix_of(device_id))
        return name

    def write_params(self, params: dict[str, ParamValue]) -> dict[str, ParamValue]:
        if "COMPASS_MOTCT" in params:
            self._saved_motct = None  # the calibration's own value now: restore must not put the old one back
        return {name: self.link.set(name, float(value)) for name, value in params.items()}

    # ------------------------------------------------------------------ current interference (issue 46)
    def measure_current_interference(self, compensation: bool = False) -> None:
        """The primary battery monitor's current with the readings; for the measurement COMPASS_MOTCT off
        (restored unless the calibration writes it), for the proof the calibration the unit now holds read
        anew (the stream is undone with it)."""
        self.stream_current = True
        if compensation:
            self._read_held()
            return
        motct = int(self.link.get("COMPASS_MOTCT"))
        if motct != 0:
            self.link.set("COMPASS_MOTCT", 0)
            if self._saved_motct is None:
                self._saved_motct = motct

    def interference_params(self, device_id: int, per_amp_ut: np.ndarray, fit: FitResult) -> dict[str, ParamValue]:
        """COMPASS_MOTn_X/Y/Z (mG/A): AP_Compass_Backend::correct_field *adds* MOT × current after the
        offsets and the DIA/ODI matrix, in the rotated frame the readings stream in (docs/firmware.md,
        *Current interference*, checked in the source) — so MOT = −10·S·c for a raw field change c µT/A
        and the matrix S written (SCALE = 1).  The firmware range is ±1000 mG/A."""
        mot = -10.0 * np.asarray(fit.soft_iron, float) @ np.asarray(per_amp_ut, float)
        names = set_names(self._suffix_of(device_id))["MOT"]
        if np.any(np.abs(mot) > MOT_RANGE_MG_PER_A):
            raise DutError(f"{', '.join(names)} would be {np.round(mot, 1).tolist()} mG/A, beyond the firmware's "
                           f"±{MOT_RANGE_MG_PER_A:g}")
        missing = self.compensation_missing(device_id)
        if missing:
            raise DutError(missing)
        self.written_sets[device_id] = self._suffix_of(device_id)
        return {name: round(float(v), 3) for name, v in zip(names, mot, strict=True)}

    def compensation_missing(self, device_id: int) -> str | None:
        # one look per connection, at the first set's: a build has COMPASS_MOTn_* for every set or none
        # (COMPASS_MOT_ENABLED, checked in the source); a read that goes unanswered while the vehicle
        # answers nothing proves nothing about the firmware, and ends the unit as an ERROR
        name = set_names("")["MOT"][0]
        if name not in self._lacks:
            try:
                self.link.get(name)
                self._lacks[name] = None
            except NotKnown as exc:
                self._lacks[name] = f"this firmware has no COMPASS_MOTn_X/Y/Z ({exc})"
        return self._lacks[name]

    def compensation_params(self) -> dict[str, ParamValue]:
        return {"COMPASS_MOTCT": 2}  # current (0 off, 1 throttle)

    def motor_test(self, throttle_pct: float, seconds: float) -> None:
        """MAV_CMD_DO_MOTOR_TEST: motor 1, throttle in percent, for ``seconds`` (0 % stops it).  A refusal
        quotes ArduCopter's own why: its checks (``motor_test.cpp``) say it in a STATUSTEXT on the link that
        asked ("Motor Test: RC not calibrated"), sent after the ACK."""
        self.link.statustexts.clear()
        result = self.link.command(ML.MAV_CMD_DO_MOTOR_TEST, 1, 0, throttle_pct, seconds, 1)
        if result != ML.MAV_RESULT_ACCEPTED:
            why = self._said("Motor Test:", MOTOR_TEST_WHY_S)
            name = RESULT_NAMES.get(result, result)
            raise DutError(f'ArduPilot refused the motor test: "{why}"' if why else
                           f"ArduPilot refused the motor test ({name}) and said no why within "
                           f"{MOTOR_TEST_WHY_S:g} s")

    def _said(self, prefix: str, within_s: float) -> str:
        """The first STATUSTEXT starting with ``prefix`` the vehicle sends within ``within_s`` ("" if none)."""
        deadline = time.monotonic() + within_s
        while True:
            said = next((t for t in self.link.statustexts if t.startswith(prefix)), "")
            if said or time.monotonic() >= deadline:
                return said
            self.link.recv("STATUSTEXT", deadline - time.monotonic())

    def left_per_amp_ut(self, device_id: int, stream_per_amp_ut: np.ndarray) -> np.ndarray:
        """The stream is the firmware's corrected field undone with the held OFS/DIA/ODI only, so the
        compensation's MOT·I is still in it: the corrected field's slope is the held matrix times it."""
        return self.held[device_id].matrix() @ np.asarray(stream_per_amp_ut, float)

    def commit(self) -> None:
        """Save the device ids: without it the compass is 'not calibrated' after reboot (PR #16591)."""
        if self.opts.force_save_device_ids:
            self.link.require_accepted(ML.MAV_CMD_PREFLIGHT_CALIBRATION, "force-save of the compass device ids",
                                       0, 76)

    # ------------------------------------------------------------------ power cycle and proof
    def reboot(self) -> None:
        """Command the reboot.  The link closing before its ACK arrived (the ACK lost on a lossy link, the
        vehicle already going down) is taken as the reboot under way, not as a lost unit: ``await_boot``
        decides — a new boot (its uptime) proves it, an old one or none is an ERROR as ever.  A refusal
        (an ACK that says no) still stops the unit."""
        try:
            self.link.require_accepted(ML.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, "reboot", 1)
        except (LinkError, UnansweredRequest) as exc:  # gone, or its ACK lost: the new boot decides
            log.info("reboot not acknowledged (%s) — waiting for the new boot to prove it", exc)
        self.link.close()  # ArduPilot drops the connection; a fresh one proves the new boot

    def release_link(self) -> None:
        self.link.close()

    def await_boot(self, since: float) -> dict[str, float]:
        def reconnect(remaining_s: float) -> None:
            self.link.close()
            self.link.open(remaining_s)

        reconnected, uptime = await_new_boot(reconnect, self.uptime_s, since, self.opts.boot_timeout_s)
        version = self.link.request_message(ML.MAVLINK_MSG_ID_AUTOPILOT_VERSION, "AUTOPILOT_VERSION")
        require_same_vehicle(self.system_id, self.link.target_system, self.product.connection, self.uid,
                             int(version.uid) if version is not None else 0)
        self._read_ids()
        self._start_prearm()  # its answers arrive while the proof reads the calibrated field
        return {"time_to_heartbeat_s": reconnected, "uptime_at_reconnect_s": uptime}

    def _start_prearm(self) -> None:
        self.link.statustexts.clear()
        self.link.require_accepted(ML.MAV_CMD_RUN_PREARM_CHECKS, "prearm check")
        self._prearm_since = time.monotonic()

    def uptime_s(self) -> float | None:
        msg = self.link.request_message(ML.MAVLINK_MSG_ID_SYSTEM_TIME, "SYSTEM_TIME")
        return None if msg is None else msg.time_boot_ms / 1000.0

    def selected_sensor_present(self) -> bool:
        return self.device_id in self.ids.values()

    def sensors_present(self) -> list[int]:
        return [i for i in self.ids.values() if i]

    def calibrated_field_ut(self, count: int, sensor: int | None = None) -> np.ndarray | None:
        """The set's own stream after the power cycle: the field the firmware corrects with the
        calibration as it holds it now (distinct readings, truncation undone)."""
        device_id = self.device_id if sensor is None else sensor
        return self.calibrated_fields_ut(count, [device_id])[device_id]

    def calibrated_fields_ut(self, count: int, sensors: list[int]) -> dict[int, np.ndarray | None]:
        """Every listed compass's calibrated stream at once (RAW_IMU, SCALED_IMU2/3 side by side):
        each compass reads at 10 Hz, so one after the other a three-compass unit waited three times
        as long for the same readings.  None for a compass the unit no longer has."""
        out: dict[int, np.ndarray | None] = {d: None for d in sensors}
        kinds = {STREAMS[SETS.index(self._suffix_of(d))]: d for d in sensors if d in self.ids.values()}
        if not kinds:
            return out
        # each compass reads at 10 Hz: its distinct readings are waited for three times as long as they take
        rows = {kind: ReadingsAtRest(count, max(self.opts.stream_timeout_s, 3.0 * count / COMPASS_HZ))
                for kind, _ in kinds}
        self.link.drain()
        started: list[int] = []
        try:
            for _, msg_id in kinds:
                self.link.set_message_interval(msg_id, 50.0)
                started.append(msg_id)
            while waiting := [kind for kind in rows if not rows[kind].done]:
                msg = self.link.recv(waiting, self.opts.stream_timeout_s)
                if msg is None:
                    late = " / ".join(waiting)
                    self.link.require_alive(f"waiting for {late} after the power cycle")
                    raise DutError(f"the vehicle answers but sent no {late} after the power cycle")
                rows[msg.get_type()].add(msg.xmag, msg.ymag, msg.zmag)
        finally:
            for msg_id in started:
                with contextlib.suppress(DutError):
                    self.link.set_message_interval(msg_id, 0)
        for (kind, _), device_id in kinds.items():
            out[device_id] = untruncate_mg(np.array(rows[kind].rows(), float)) / 10.0
        return out

    def persistence_problems(self) -> list[str]:
        """Run ArduPilot's arming checks: a compass whose DEV_ID was not saved is 'not calibrated'.

        Every compass PreArm text fails the unit: ArduPilot's text does not say which compass, and
        a compass in use that is left uncalibrated blocks arming anyway (disable it with
        COMPASS_USEn = 0 or calibrate it too).

        The checks are asked for as soon as the new boot is proven (:meth:`await_boot`): the station reads
        the calibrated field meanwhile, and the texts have had ``prearm_wait_s`` when they are read here."""
        if self._prearm_since is None:
            self._start_prearm()
        left = self._prearm_since + self.opts.prearm_wait_s - time.monotonic()
        if left > 0:
            self.link.recv("NO_SUCH_MESSAGE", left)  # collect STATUSTEXT meanwhile
        self._prearm_since = None
        return sorted({t for t in self.link.statustexts if t.startswith(COMPASS_PREARM)})
