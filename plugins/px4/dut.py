"""The PX4 DUT backend: calibrate every magnetometer through MAVSDK, persist, prove it survived.

Sequence as the core's phases drive it: connect (discovery, firmware, the sensor by device id
through the MAVLink shell or, where it does not answer, from parameters, streams and the station
file — see :mod:`.discovery` — calibration slot by id) → prepare (SENS_MAG_AUTOCAL off) → samples
(SCALED_IMU/2/3 of each sensor's uORB instance: raw, mG, in one stream with SCALED_IMU's accelerometer
for gravity) → parameters (CAL_MAGn_* of each sensor's slot; CAL_MAGn_ROT where the mounting check
fixes an external sensor's orientation) → commit (MAV_CMD_PREFLIGHT_STORAGE param1 = 1) → reboot,
fresh link, read back, every sensor still there → restore.  Several sensors need their device ids,
which only the shell tells: without it one sensor is calibrated, as the station file names it.

The online bias estimator (MBE_ENABLE) is left alone: it acts on the calibrated
vehicle_magnetometer (HIGHRES_IMU), not on the raw sensor_mag that SCALED_IMU carries, and a
change would need a reboot to take effect.
"""

from __future__ import annotations

import contextlib
import logging
import queue
import re
import time
from collections.abc import Iterator
from typing import TYPE_CHECKING

import numpy as np

from magline.plugin import (
    INT16_MG_RANGE_UT,
    CalibratedBesideRaw,
    DutError,
    Magnetometer,
    NotRestored,
    SensorStreams,
    StationFault,
    UnitInfo,
    await_new_boot,
    configured_rotation,
    get_listening,
    mavlink2_frame_bytes,
    require_same_vehicle,
    untruncate_mg,
)
from magline.plugins.px4 import factory_store
from magline.plugins.px4.calibration import (
    PRIO_EXTERNAL,
    PRIO_INTERNAL,
    ROT_CUSTOM_EULER,
    SLOTS,
    choose_slot,
    euler_rotation,
    fit_to_params,
    is_int_param,
    rotation_params,
)
from magline.plugins.px4.discovery import Identified, from_shell, without_shell
from magline.plugins.px4.link import Px4Link

if TYPE_CHECKING:
    from magline.plugin import FitResult, ParamValue, Product, SampleChunk
    from magline.plugins.px4.options import Px4Options

STREAMS = (("SCALED_IMU", 26), ("SCALED_IMU2", 116), ("SCALED_IMU3", 129))  # uORB sensor_mag instance 0/1/2
MAV_CMD_SET_MESSAGE_INTERVAL, MAV_CMD_REQUEST_MESSAGE, MAV_CMD_PREFLIGHT_STORAGE = 511, 512, 245
MAV_CMD_DO_MOTOR_TEST = 209
SYSTEM_TIME = ("SYSTEM_TIME", 2)
HIGHRES_IMU = ("HIGHRES_IMU", 105)  # the calibrated vehicle_magnetometer, Gauss
UT_PER_GAUSS = 100.0
MG_PER_UT = 10.0

log = logging.getLogger("magline.px4")
CHUNK = 10
CHUNK_WITHIN_S = 0.25  # a slow compass's readings handed on at least this often
MAVLINK_MSG_ID_BATTERY_STATUS = 147
BATTERY_RATE_HZ = 10.0  # BATTERY_STATUS during a current sweep
RESTORE_RECONNECT_S = 3.0  # a vehicle that does not answer by then is reported as not restored
DEVICE_ID = re.compile(r"device_id:\s*(\d+)")
EXTERNAL = re.compile(r"is_external:\s*(\w+)")


class Px4Dut:
    def __init__(self, product: Product, options: Px4Options) -> None:
        self.product = product
        self.opts = options
        self.link = Px4Link(product.connection, connect_timeout_s=options.connect_timeout_s)
        self.ident: Identified | None = None
        self.shell_answers = False
        self.present = True  # after a power cycle: is the calibrated sensor still there?
        self._saved_at: float | None = None  # when the forced save was asked (a supply cut waits after it)
        self.now_present: list[int] = []  # after a power cycle: the device ids the unit has
        self._streaming_count = 0  # magnetometer streams seen without the shell
        self.device_id = 0
        self.instance = 0
        self.slot = 0
        self.sensors: dict[int, dict] = {}  # device id → instance, slot, prio, external (every sensor known)
        self.chosen: list[int] = []  # the sensors this run calibrates, primary first
        self.with_odiag = True
        self.with_euler = False
        self._saved_autocal: int | None = None
        self._saved_comp_typ: int | None = None  # CAL_MAG_COMP_TYP switched off for the current sweep
        self._param_known: dict[str, bool] = {}  # whether this firmware has a name, asked once
        self.stream_current = False  # the sweep asked for the unit's battery current with the readings
        self.system_id = 0
        self.uid = 0
        self._found: list[tuple[int, bool]] = []  # (device id, external) per sensor_mag instance, from the shell
        self._written_names: list[str] = []  # every parameter this run wrote (the factory store's proof reads them)

    # ------------------------------------------------------------------ link
    def connect(self) -> UnitInfo:
        self.link.open()
        self.system_id = self.link.target_system  # another one answering later is another vehicle
        version = self.link.firmware()
        self.uid = self.link.hardware_uid()  # the board itself: a second one may share the system id
        firmware = ".".join(map(str, version)) if version else "unknown"
        # what the firmware can hold, read from its own parameter list: a build from an untagged tree
        # reports 0.0.0 whatever it has, and a version string proves nothing (docs/firmware.md, *Versions*)
        self.with_odiag = self._has_param("CAL_MAG0_XODIAG")
        self.with_euler = self._has_param("CAL_MAG0_ROLL")
        if self.product.persist == "factory-storage" and not self._has_param(factory_store.MODE_PARAM):
            raise DutError(f"this PX4 has no {factory_store.MODE_PARAM}: it cannot keep a factory calibration, and "
                           "the product asks for persist: factory-storage (nothing was written)")
        slot_ids = [int(self.link.get(f"CAL_MAG{n}_ID", True)) for n in range(SLOTS)]
        self.ident = self._identify(slot_ids)
        self.device_id, self.instance = self.ident.device_id, self.ident.instance
        known = self._found if self.shell_answers else [(self.device_id, self.ident.external)]
        instances = ([i for i, _ in enumerate(self._found)] if self.shell_answers else [self.instance])
        self.sensors = {}
        taken = list(slot_ids)
        for (device_id, external), instance in zip(known, instances, strict=True):
            slot = choose_slot(taken, device_id, preferred=instance)
            taken[slot] = device_id  # two new sensors never share a free slot
            prio = int(self.link.get(f"CAL_MAG{slot}_PRIO", True))
            self.sensors[device_id] = {"instance": instance, "slot": slot, "external": external,
                                       "prio": prio if prio >= 1 else (PRIO_EXTERNAL if external else PRIO_INTERNAL)}
        self.slot, self.prio = self.sensors[self.device_id]["slot"], self.sensors[self.device_id]["prio"]
        self.chosen = [self.device_id]
        board_rot = int(self.link.get("SENS_BOARD_ROT", True))
        return UnitInfo(autopilot="PX4", firmware=firmware, sensors=list(self.ident.sensors),
                        selected_sensor=self.device_id, soft_iron_model="full" if self.with_odiag else "diagonal",
                        extra={"cal_slot": self.slot, "sensor_instance": self.instance,
                               "identified_by": self.ident.by,
                               "soft_iron_model_why": "the firmware has CAL_MAG0_XODIAG" if self.with_odiag else
                               "the firmware has no CAL_MAGn_xODIAG (diagonal soft iron only)"},
                        magnetometers=[self._magnetometer(d, board_rot) for d in self.sensors])

    def _magnetometer(self, device_id: int, board_rot: int) -> Magnetometer:
        """SCALED_IMU carries sensor_mag in the sensor's own axes; PX4 turns an external sensor into the
        body with CAL_MAGn_ROT (≥ 0), an internal one with the board's rotation (no parameter of its own
        can fix an internal sensor's mounting)."""
        info = self.sensors[device_id]
        p = f"CAL_MAG{info['slot']}_"
        rot = int(self.link.get(p + "ROT", True))
        external = info["external"] if info["external"] is not None else rot >= 0
        custom = None
        if external and rot == ROT_CUSTOM_EULER and self.with_euler:  # held as custom Euler angles
            custom = euler_rotation(*(float(self.link.get(p + a, False)) for a in ("ROLL", "PITCH", "YAW"))).tolist()
        return Magnetometer(device_id=device_id, label=f"CAL_MAG{info['slot']}", external=external,
                            orientation=max(rot, 0) if external else board_rot, readings_rotated=False,
                            fix_params=[p + "ROT"] if external else [], range_ut=INT16_MG_RANGE_UT,
                            rotation=custom)

    def use_magnetometers(self, device_ids: list[int]) -> None:
        self.chosen = list(device_ids)

    def _has_param(self, name: str) -> bool:
        """Whether this firmware has ``name``, asked once per link: the first unknown name costs a read's
        retries, then the firmware's list of parameters answers for every other (``Px4Link.listed_names``)."""
        known = self._param_known
        if name not in known:
            try:
                self.link.get(name, is_int_param(name))
                known[name] = True
            except DutError:
                known[name] = False
        return known[name]

    def _identify(self, slot_ids: list[int]) -> Identified:
        """The shell where it answers; otherwise parameters, streams and the station file."""
        try:
            found = self._discover()
        except StationFault as exc:
            self.shell_answers = False
            return without_shell(self._streaming_instances(), slot_ids, self.product.magnetometer,
                                 self.opts.sensor_instance, f"the PX4 shell does not answer ({exc})")
        self.shell_answers = True
        self._found = found
        return from_shell(found, self.product.magnetometer)

    def _discover(self) -> list[tuple[int, bool]]:
        """Device id of each sensor_mag instance, from the MAVLink shell (SCALED_IMU carries none)."""
        found = []
        for instance in range(len(STREAMS)):
            out = self.link.shell(f"listener sensor_mag -i {instance} -n 1", self.opts.shell_timeout_s)
            match = DEVICE_ID.search(out)
            if match is None:
                break
            ext = EXTERNAL.search(out)
            found.append((int(match.group(1)), bool(ext and ext.group(1) in ("True", "1"))))
        return found

    def _streaming_instances(self) -> list[int]:
        """The sensor_mag instances whose SCALED_IMU/2/3 answers a request (one message each).

        REQUEST_MESSAGE rather than a stream: nothing keeps running, and nothing else changes."""
        out: list[int] = []
        for instance, (kind, msg_id) in enumerate(STREAMS):
            inbox, handle = self.link.subscribe(kind)
            try:
                for _ in range(3):
                    if self.link.command(MAV_CMD_REQUEST_MESSAGE, msg_id) != 0:
                        break  # the firmware has no such stream
                    try:
                        inbox.get(timeout=self.opts.stream_probe_s / 3)
                        out.append(instance)
                        break
                    except queue.Empty:
                        continue
            finally:
                self.link.unsubscribe(handle)
        self._streaming_count = len(out)
        return out

    def close(self) -> None:
        self.link.close()

    @property
    def boot_timeout_s(self) -> float:
        """How long the station waits for the new boot after a power cycle (the operator's countdown)."""
        return self.opts.boot_timeout_s

    # ------------------------------------------------------------------ prepare / restore
    def prepare(self) -> None:
        autocal = int(self.link.get("SENS_MAG_AUTOCAL", True))
        if autocal != 0:  # the firmware must not write its own calibration into a slot meanwhile
            self.link.set("SENS_MAG_AUTOCAL", 0, True)
            self._saved_autocal = autocal

    def restore(self) -> None:
        """SENS_MAG_AUTOCAL (and CAL_MAG_COMP_TYP, switched off for a current sweep and not written since)
        back, saved (else a power-off right after the station leaves them off); after a closed link, one
        short reconnect is tried first."""
        saved = {name: value for name, value in (("SENS_MAG_AUTOCAL", self._saved_autocal),
                                                 ("CAL_MAG_COMP_TYP", self._saved_comp_typ)) if value is not None}
        self.stream_current = False
        if not saved:
            return
        try:
            if not self.link.is_open:
                self.link.reopen(min(self.opts.connect_timeout_s, RESTORE_RECONNECT_S))
            for name, value in saved.items():
                self.link.set(name, value, True)
            self.commit()
        except DutError as exc:
            raise NotRestored(str(exc), {name: f"0 (was {value})" for name, value in saved.items()}) from exc
        self._saved_autocal = self._saved_comp_typ = None

    # ------------------------------------------------------------------ data
    def samples(self, rate_hz: float) -> Iterator[SampleChunk]:
        """Every chosen sensor's SCALED_IMU/2/3 at once, SCALED_IMU's accelerometer for gravity; each
        sensor's repeats dropped on its own."""
        by_kind = {STREAMS[self.sensors[d]["instance"]][0]: d for d in self.chosen}
        kinds = list(dict.fromkeys([STREAMS[0][0], *by_kind]))
        ids = dict(STREAMS)
        if self.link.port is not None:
            battery = {"BATTERY_STATUS": (mavlink2_frame_bytes(MAVLINK_MSG_ID_BATTERY_STATUS), BATTERY_RATE_HZ)}
            self.link.port.require_capacity({k: (mavlink2_frame_bytes(ids[k]), rate_hz) for k in kinds},
                                            battery if self.stream_current else None)
        listened = [*kinds, "BATTERY_STATUS"] if self.stream_current else kinds
        inbox, handles = self.link.subscribe_all(listened)
        streams = SensorStreams(self.device_id, self.chosen, lambda _, mg: mg / MG_PER_UT)
        try:
            for kind in kinds:
                self.link.require_accepted(MAV_CMD_SET_MESSAGE_INTERVAL, f"{kind} stream request", ids[kind],
                                           1e6 / rate_hz)
            if self.stream_current:  # battery_status instance 0: what CAL_MAG_COMP_TYP = 2 multiplies by
                self.link.require_accepted(MAV_CMD_SET_MESSAGE_INTERVAL, "BATTERY_STATUS stream request",
                                           MAVLINK_MSG_ID_BATTERY_STATUS, 1e6 / BATTERY_RATE_HZ)
            while True:
                try:
                    kind, msg = get_listening(inbox, self.opts.stream_timeout_s)
                except queue.Empty:
                    self.link.require_alive(f"link lost during acquisition: no {'/'.join(kinds)} for "
                                            f"{self.opts.stream_timeout_s:g} s")
                    raise DutError(f"the vehicle answers but sent no {'/'.join(kinds)} for "
                                   f"{self.opts.stream_timeout_s:g} s: magnetometer {self.device_id} delivers no "
                                   "readings") from None
                if kind == "BATTERY_STATUS":
                    if int(msg["id"]) == 0:
                        streams.current(float(msg["current_battery"]))
                    continue
                if kind == STREAMS[0][0]:
                    streams.accel(float(msg["time_boot_ms"]), msg["xacc"], msg["yacc"], msg["zacc"])
                # SCALED_IMU is sent whenever the IMU *or* the magnetometer updated, with the IMU's
                # time: the same magnetometer reading repeats at the IMU's rate (dropped here)
                if kind in by_kind:
                    streams.mag(by_kind[kind], float(msg["time_boot_ms"]), msg["xmag"], msg["ymag"], msg["zmag"])
                if streams.ready(CHUNK, CHUNK_WITHIN_S):
                    yield streams.take()
        finally:
            for kind in kinds:
                with contextlib.suppress(DutError):  # a lost link stops the stream by itself
                    self.link.command(MAV_CMD_SET_MESSAGE_INTERVAL, ids[kind], -1)
            if self.stream_current:
                with contextlib.suppress(DutError):
                    self.link.command(MAV_CMD_SET_MESSAGE_INTERVAL, MAVLINK_MSG_ID_BATTERY_STATUS, -1)
            for handle in handles:
                self.link.unsubscribe(handle)

    # ------------------------------------------------------------------ parameters
    def calibration_params(self, fit: FitResult, sensor: int | None = None) -> dict[str, ParamValue]:
        device_id = self.device_id if sensor is None else sensor
        info = self.sensors[device_id]
        params = fit_to_params(fit, info["slot"], device_id, info["prio"], self.with_odiag)
        if fit.model == "affine":  # a coil measured the misalignment too: hold it where PX4 can
            if self.with_euler and info["external"]:
                params |= rotation_params(np.array(fit.extra["rotation"]), info["slot"])
            else:
                log.warning("misalignment of %.2f° not written: PX4 holds a custom rotation only for external "
                            "magnetometers from firmware 1.15", fit.extra.get("misalignment_deg", 0.0))
        return params

    # ------------------------------------------------------------------ current interference (issue 46)
    def measure_current_interference(self, compensation: bool = False) -> None:
        """battery_status instance 0 with the readings; for the measurement CAL_MAG_COMP_TYP off
        (restored unless the calibration writes it).  SCALED_IMU is the raw sensor either way."""
        self.stream_current = True
        if compensation:
            return
        comp_typ = int(self.link.get("CAL_MAG_COMP_TYP", True))
        if comp_typ != 0:
            self.link.set("CAL_MAG_COMP_TYP", 0, True)
            if self._saved_comp_typ is None:
                self._saved_comp_typ = comp_typ

    def interference_params(self, device_id: int, per_amp_ut: np.ndarray, fit: FitResult) -> dict[str, ParamValue]:
        """CAL_MAGn_X/Y/ZCOMP (G/kA = mG/A): Magnetometer::Correct adds power·COMP to the *raw* reading
        before the offset, in the sensor's own axes (docs/firmware.md, *Current interference*, checked in
        the source) — the frame SCALED_IMU streams in — so COMP = −10·c for a raw field change c µT/A,
        whatever the calibration."""
        slot = self.sensors[device_id]["slot"]
        names = [f"CAL_MAG{slot}_{a}COMP" for a in "XYZ"]
        missing = self.compensation_missing(device_id)
        if missing:
            raise DutError(missing)
        comp = -10.0 * np.asarray(per_amp_ut, float)
        return {name: round(float(v), 4) for name, v in zip(names, comp, strict=True)}

    def compensation_missing(self, device_id: int) -> str | None:
        # one look per firmware: a build has the parameters for every slot or none
        if self._has_param("CAL_MAG0_XCOMP"):
            return None
        return "this firmware has no CAL_MAGn_XCOMP/YCOMP/ZCOMP (CAL_MAG0_XCOMP unknown)"

    def compensation_params(self) -> dict[str, ParamValue]:
        # 2: the current of battery_status instance 0, where a BATTERY_STATUS from the power module lands
        return {"CAL_MAG_COMP_TYP": 2}

    def motor_test(self, throttle_pct: float, seconds: float) -> None:
        """MAV_CMD_DO_MOTOR_TEST: motor 1, throttle in percent, for ``seconds`` (0 % stops it)."""
        result = self.link.command(MAV_CMD_DO_MOTOR_TEST, 1, 0, throttle_pct, seconds, 1)
        if result != 0:
            raise DutError(f"PX4 refused the motor test (MAV_RESULT {result}: a safety switch on, or not landed)")

    def left_per_amp_ut(self, device_id: int, stream_per_amp_ut: np.ndarray) -> np.ndarray:
        """SCALED_IMU is the raw sensor_mag: the firmware's corrected slope is R·S·(c + COMP), with the
        slot's parameters as the unit holds them now (read back) — 0 when the compensation is off."""
        slot = self.sensors[device_id]["slot"]
        p = f"CAL_MAG{slot}_"
        comp_on = int(self.link.get("CAL_MAG_COMP_TYP", True)) in (2, 3)
        comp = np.array([float(self.link.get(f"{p}{a}COMP", False)) for a in "XYZ"]) / 10.0 if comp_on else np.zeros(3)
        scale = np.diag([float(self.link.get(f"{p}{a}SCALE", False)) for a in "XYZ"])
        if self.with_odiag:
            x, y, z = (float(self.link.get(f"{p}{a}ODIAG", False)) for a in "XYZ")
            scale[0, 1] = scale[1, 0] = x
            scale[0, 2] = scale[2, 0] = y
            scale[1, 2] = scale[2, 1] = z
        rotation = self.body_rotations([device_id])[device_id]
        return rotation @ scale @ (np.asarray(stream_per_amp_ut, float) + comp)

    def orientation_params(self, device_id: int, value: int) -> dict[str, ParamValue]:
        """CAL_MAGn_ROT of the sensor's slot: how PX4 turns an external sensor into the body (its custom
        Euler angles zeroed where the firmware has them: a non-zero one forces ROT = 100, docs/firmware.md)."""
        p = f"CAL_MAG{self.sensors[device_id]['slot']}_"
        zeroed = {p + a: 0.0 for a in ("ROLL", "PITCH", "YAW")} if self.with_euler else {}
        return {p + "ROT": int(value)} | zeroed

    def rotation_params(self, device_id: int, rotation: np.ndarray) -> dict[str, ParamValue]:
        """A measured mounting as PX4's custom rotation (CAL_MAGn_ROT = 100, ROLL/PITCH/YAW): only an
        external sensor of a firmware that has the angles can hold one (internal ones follow the board)."""
        info = self.sensors[device_id]
        if not self.with_euler:
            raise DutError("this firmware has no CAL_MAGn_ROLL/PITCH/YAW (PX4 1.15 and later hold a custom "
                           "rotation)")
        if not info["external"]:
            raise DutError("PX4 turns an internal magnetometer with the board (SENS_BOARD_ROT), never on its own")
        return rotation_params(rotation, info["slot"])

    def read_params(self, names: list[str]) -> dict[str, ParamValue]:
        return {n: self.link.get(n, is_int_param(n)) for n in names}

    def write_params(self, params: dict[str, ParamValue]) -> dict[str, ParamValue]:
        if "CAL_MAG_COMP_TYP" in params:
            self._saved_comp_typ = None  # the calibration's own value now: restore must not put the old one back
        self._written_names += [n for n in params if n not in self._written_names]
        return {n: self.link.set(n, v, is_int_param(n)) for n, v in params.items()}

    def commit(self) -> None:
        """Force the save: the echo only means "in RAM", and autosave may be held back 2 s.

        No wait here: a commanded reboot waits by itself for the save (PX4's shutdown lock, held by
        the save), so the usual power cycle goes straight on; only a supply cut waits, in
        :meth:`release_link`."""
        if self.opts.force_save:  # param1 = 1 saves; 3 would reset every calibration
            self.link.require_accepted_by_worker(MAV_CMD_PREFLIGHT_STORAGE, "forced parameter save", 1)
            self._saved_at = time.monotonic()

    # ------------------------------------------------------------------ factory calibration store
    def store_factory_calibration(self, mode_after: int) -> str:
        said = factory_store.copy_into_store(self.link, mode_after, self.opts.factory_store_timeout_s)
        self._saved_at = time.monotonic()
        return said

    def factory_store_contents(self, written: dict[str, ParamValue]) -> dict[str, ParamValue | None] | None:
        """The store over the MAVLink shell (``bsondump``); None where the shell does not answer (POSIX
        builds) — the station then says the store was not read back."""
        if not self.shell_answers:
            return None
        try:
            out = self.link.shell(f"bsondump {factory_store.FACTORY_STORE}", self.opts.shell_timeout_s)
        except StationFault:
            return None
        return factory_store.store_contents(out, written)

    def restore_from_factory_store(self, since: float) -> dict[str, ParamValue]:
        names = [n for n in self._written_names if factory_store.held_by_store(n)]
        factory_store.reset_calibration(self.link)
        self.link.close()
        self.await_boot(since)
        return factory_store.read_named(self.link, names)

    # ------------------------------------------------------------------ power cycle and proof
    def reboot(self) -> None:
        self.link.reboot()

    def release_link(self) -> None:
        """The power is about to be cut.  PREFLIGHT_STORAGE is ACKed before its save runs and PX4 sends
        nothing when the save ends (docs/firmware.md, *Persistence*), so no event exists to wait for: the
        cut waits ``save_settle_s`` after the save was asked, then the read-back after the boot proves it."""
        if self._saved_at is not None:
            time.sleep(max(0.0, self._saved_at + self.opts.save_settle_s - time.monotonic()))
            self._saved_at = None
        self.link.close()

    def await_boot(self, since: float) -> dict[str, float]:
        # a fresh MAVSDK instance per try: nothing cached from the old boot can answer a read
        reconnected, uptime = await_new_boot(self.link.reopen, self.uptime_s, since, self.opts.boot_timeout_s)
        require_same_vehicle(self.system_id, self.link.target_system, self.product.connection, self.uid,
                             self.link.hardware_uid())
        if self.shell_answers:
            self.now_present = [d for d, _ in self._discover()]
            self.present = self.device_id in self.now_present
        else:  # no shell: the instance still streams (its device id is checked in the slots)
            self.present = self.instance in self._streaming_instances()
            self.now_present = [self.device_id] if self.present else []
        return {"time_to_heartbeat_s": reconnected, "uptime_at_reconnect_s": uptime}

    def uptime_s(self) -> float | None:
        inbox, handle = self.link.subscribe(SYSTEM_TIME[0])
        try:
            self.link.require_accepted(MAV_CMD_REQUEST_MESSAGE, "SYSTEM_TIME request", SYSTEM_TIME[1])
            return get_listening(inbox, 2.0)["time_boot_ms"] / 1000.0
        except queue.Empty:
            return None
        finally:
            self.link.unsubscribe(handle)

    def selected_sensor_present(self) -> bool:
        return self.present

    def sensors_present(self) -> list[int]:
        return list(self.now_present)

    def calibrated_field_ut(self, count: int, sensor: int | None = None) -> np.ndarray | None:
        """HIGHRES_IMU's magnetic field (Gauss, calibrated by the firmware), when this sensor is the
        unit's only magnetometer: with several, it carries whichever PX4's voter selected."""
        if len(self.chosen) > 1:
            return None
        both = self.raw_and_calibrated_ut(count)
        return None if both is None else both.calibrated_ut

    def raw_and_calibrated_ut(self, count: int) -> CalibratedBesideRaw | None:
        """``count`` of the firmware's calibrated readings (HIGHRES_IMU, Gauss), each beside the raw
        reading of every calibrated sensor it may have been made from (the latest SCALED_IMU/2/3 of that
        sensor at or before its time, mG, truncation undone), all in µT, with the rotation PX4 turns each
        sensor's calibrated reading into the body by — what proves the calibration the firmware
        *applies* (issue 50).  HIGHRES_IMU carries the
        sensor PX4's voter selected, which MAVLink does not name, so the station finds which one it is.
        None where HIGHRES_IMU may carry a sensor this run did not calibrate (the unit has more than it
        calibrates, or several stream and no shell names them) or the firmware does not send it.  Without the
        shell, a slot's id beside the one stream that carries data is no second sensor: a POSIX build's
        startup presets CAL_MAG0_ID and CAL_MAG1_ID whatever it has (PX4 SITL: one sensor streams)."""
        others = set(self.ident.sensors) - set(self.chosen) if self.shell_answers else self._streaming_count > 1
        if others:
            return None
        instances = {device_id: self.sensors[device_id]["instance"] for device_id in self.chosen}
        if any(i >= len(STREAMS) for i in instances.values()):
            return None
        raw_kinds = {STREAMS[i][0]: device_id for device_id, i in instances.items()}
        kind, msg_id = HIGHRES_IMU
        rate_ids = [msg_id] + [STREAMS[i][1] for i in instances.values()]
        inbox, handles = self.link.subscribe_all([kind, *raw_kinds])
        latest: dict[int, list[tuple[float, tuple[float, float, float]]]] = {d: [] for d in instances}
        pairs: list[tuple[dict[int, tuple[float, float, float]], tuple[float, float, float]]] = []
        try:
            for wanted, rate_id in zip([kind, *raw_kinds], rate_ids, strict=True):
                self.link.require_accepted(MAV_CMD_SET_MESSAGE_INTERVAL, f"{wanted} stream request", rate_id, 1e6 / 50)
            while len(pairs) < count:
                try:
                    got, msg = get_listening(inbox, self.opts.stream_timeout_s)
                except queue.Empty:
                    self.link.require_alive(f"waiting for {kind} and {', '.join(raw_kinds)}")
                    return None  # the firmware does not send them: nothing to prove with
                if got in raw_kinds:
                    latest[raw_kinds[got]].append((float(msg["time_boot_ms"]), (msg["xmag"], msg["ymag"], msg["zmag"])))
                    continue
                at = float(msg["time_usec"]) / 1000.0
                made_from = {d: [row for t, row in seen if t <= at] for d, seen in latest.items()}
                if all(made_from.values()):
                    behind = {d: rows[-1] for d, rows in made_from.items()}
                    pairs.append((behind, (msg["xmag"], msg["ymag"], msg["zmag"])))
        finally:
            for rate_id in rate_ids:
                with contextlib.suppress(DutError):
                    self.link.command(MAV_CMD_SET_MESSAGE_INTERVAL, rate_id, -1)
            for handle in handles:
                self.link.unsubscribe(handle)
        raws = {d: untruncate_mg(np.array([raw[d] for raw, _ in pairs], float)) / MG_PER_UT for d in instances}
        return CalibratedBesideRaw(calibrated_ut=np.array([c for _, c in pairs], float) * UT_PER_GAUSS, raw_ut=raws,
                                   to_body=self.body_rotations(list(instances)), less_estimated_bias=True)

    def body_rotations(self, device_ids: list[int]) -> dict[int, np.ndarray]:
        """The rotation PX4 applies after each sensor's calibration, read from the parameters it holds
        now: the sensor's (external: CAL_MAGn_ROT or its custom Euler angles) or the board's (internal:
        SENS_BOARD_ROT), behind the board's level adjustment SENS_BOARD_X/Y/Z_OFF where the firmware
        has it (roll, pitch, yaw in degrees; PX4 applies it to external sensors too).  The board's
        parameters are read once for all sensors."""
        board_rot = int(self.link.get("SENS_BOARD_ROT", True))
        level = np.eye(3)
        if self._has_param("SENS_BOARD_X_OFF"):
            level = euler_rotation(*(float(self.link.get(f"SENS_BOARD_{a}_OFF", False)) for a in "XYZ"))
        return {d: level @ configured_rotation(self._magnetometer(d, board_rot)) for d in device_ids}

    def persistence_problems(self) -> list[str]:
        """The firmware uses the *first* slot whose ID matches; it must be the one written."""
        ids = [int(self.link.get(f"CAL_MAG{n}_ID", True)) for n in range(SLOTS)]
        problems = []
        for device_id in self.chosen:
            slot = self.sensors[device_id]["slot"]
            used = ids.index(device_id) if device_id in ids else None
            if used != slot:
                where = "no slot" if used is None else f"CAL_MAG{used}"
                problems.append(f"magnetometer {device_id} is calibrated by {where}, not by the written CAL_MAG{slot}")
        return problems
