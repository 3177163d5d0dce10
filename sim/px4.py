"""A simulated PX4 flight controller (behaviour per ``docs/firmware.md``, *PX4*).

What it reproduces, because each is a trap for a factory tool:
- integer parameters are byte-wise encoded and PARAM_SET must carry the exact type; a wrong type
  or an unknown name is dropped without a reply;
- calibration slots are matched by ``CAL_MAGn_ID``, never by position; a sensor without a matching
  slot is used uncalibrated; ``XODIAG/YODIAG/ZODIAG`` exist only from firmware 1.12;
- the PARAM_VALUE echo only means "in RAM": autosave runs 300 ms after a change and at most once
  per 2 s, so a reboot soon after a write loses it unless MAV_CMD_PREFLIGHT_STORAGE (param1 = 1)
  forced a save; a save in progress finishes before a commanded reboot but not before a power cut;
- SCALED_IMU/2/3 stream the raw sensor in mG (int16 by truncation toward zero); HIGHRES_IMU the
  calibrated field in Gauss less EKF2's bias estimate, which learns the field's difference to the
  firmware's model of it from the boot on; each driver publishes at its own rate and a stream faster than that
  carries the latest reading again with a fresh (IMU) timestamp;
- with SENS_MAG_AUTOCAL = 1 the firmware writes its own calibration into an uncalibrated slot;
- the device id of each ``sensor_mag`` instance is visible through the MAVLink shell
  (``listener sensor_mag -i N``), as on a NuttX board; with ``shell=False`` the shell echoes each
  line and runs none, as POSIX builds (SITL) do over MAVLink (seen on PX4 SITL);
- ``preset_ids=True``: the slot ids are preset to the detected sensors, as POSIX startup scripts
  do (``param set-default CAL_MAG0_ID …``), so they are defaults, not stored values;
- the factory calibration storage (``/fs/mtd_caldata``, ``docs/firmware.md`` *Factory calibration
  storage*): with ``SYS_FAC_CAL_MODE`` ≥ 1 the commander's gyro calibration (MAV_CMD_PREFLIGHT_CALIBRATION,
  param1 = 1, the unit still) exports every ``CAL_*`` but ``CAL_MAG_SIDES`` and ``*_PRIO`` (mode 2: and
  no ``CAL_MAG*``) and every ``TC_*`` there, saying so in STATUSTEXT as PX4 does; a board with the
  partition loads it at boot before the user's parameters; ``bsondump /fs/mtd_caldata`` in the shell
  prints it; MAV_CMD_PREFLIGHT_STORAGE param1 = 3 resets the calibration parameters, saves and reboots;
- the commander's worker thread: a calibration and a forced save (MAV_CMD_PREFLIGHT_STORAGE) run there,
  and either command is refused with TEMPORARILY_REJECTED while it is busy — which it still is for
  ``WORKER_REAP_S`` after a calibration has said "done" or a forced save has ended, until the
  commander's next cycle collects the result (seen on PX4 SITL: the save asked right after the factory
  store's gyro calibration was refused).
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray
from pymavlink.dialects.v20 import ardupilotmega as mavlink
from scipy.spatial.transform import Rotation

from magline.core.mounting import orientation_matrix
from magline.sim.magnetometers import SimMagnetometer
from magline.sim.params import INT32, REAL32, ParamSpec, ParamValue, bytewise_from_wire, bytewise_to_wire
from magline.sim.vehicle import ACCEPTED, DENIED, UNSUPPORTED, Power, SimulatedAutopilot, int16_mg

SLOTS = 4
AXES = ("X", "Y", "Z")
FACTORY_STORE = "/fs/mtd_caldata"
GYRO_CAL_S = 2.0  # how long the commander's gyro calibration takes (divided by a sped-up motion's speed)
WORKER_REAP_S = 0.1  # the worker thread stays busy this long after its task ended (the commander's next cycle)
CAL_STARTED, CAL_DONE, CAL_FAILED = ("[cal] calibration started: 2 {}", "[cal] calibration done: {}",
                                     "[cal] calibration failed: {}")  # calibration_messages.h
SHELL_DEVICE = mavlink.SERIAL_CONTROL_DEV_SHELL
SHELL_REPLY = mavlink.SERIAL_CONTROL_FLAG_REPLY


def slot_params(n: int, with_odiag: bool, with_euler: bool = False) -> list[ParamSpec]:
    p = f"CAL_MAG{n}_"
    specs = [ParamSpec(p + "ID", INT32, 0), ParamSpec(p + "PRIO", INT32, -1), ParamSpec(p + "ROT", INT32, -1)]
    specs += [ParamSpec(f"{p}{a}OFF", REAL32, 0.0) for a in AXES]
    specs += [ParamSpec(f"{p}{a}SCALE", REAL32, 1.0) for a in AXES]
    if with_odiag:
        specs += [ParamSpec(f"{p}{a}ODIAG", REAL32, 0.0) for a in AXES]
    specs += [ParamSpec(f"{p}{a}COMP", REAL32, 0.0) for a in AXES]
    if with_euler:
        specs += [ParamSpec(p + angle, REAL32, 0.0) for angle in ("ROLL", "PITCH", "YAW")]
    return specs


class Px4Sim(SimulatedAutopilot):
    flavour = "px4"
    # a battery without a current sensor: PX4's battery_status current_a is −1 A, and its BATTERY_STATUS
    # stream sends current × 100 (its SITL battery reads −1 A)
    CURRENT_NOT_MEASURED_CA = -100
    autopilot = mavlink.MAV_AUTOPILOT_PX4
    capabilities = (mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
                    | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                    | mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2)
    default_listen = "udp:127.0.0.1:14550"
    storage_name = "px4-parameters.json"
    stream_sensor: ClassVar[dict[int, int]] = {
        mavlink.MAVLINK_MSG_ID_SCALED_IMU: 0, mavlink.MAVLINK_MSG_ID_SCALED_IMU2: 1,
        mavlink.MAVLINK_MSG_ID_SCALED_IMU3: 2, mavlink.MAVLINK_MSG_ID_HIGHRES_IMU: 0}
    AUTOSAVE_DELAY_S = 0.3
    REBOOT_DELAY_S = 0.4
    # EKF2's magnetometer bias estimate, which HIGHRES_IMU subtracts (HIGHRES_IMU.hpp: magnetometer_ga −
    # estimator_sensor_bias.mag_bias).  From the boot on, a unit at rest, it learns the difference between the
    # field the compass reads and the firmware's model of the field there (the World Magnetic Model at its GPS
    # position).  On PX4 SITL (752ecd3, a still level unit, its field fed 1–2 µT from the model's): 0.09 µT at
    # the first readings, 0.48 µT two seconds on — (−0.31, 0.0, +0.37) µT off the calibrated field — then held
    # (docs/firmware.md, *Current interference*).  Modelled: that difference, learnt at once (the station reads
    # HIGHRES_IMU two to four seconds after a boot, when SITL's estimate had learnt it).  Not modelled: the
    # estimate's answer to a change of the field (on SITL tens of seconds, spread over other axes): the station
    # reads HIGHRES_IMU only just after a boot.
    MODEL_FIELD_OFFSET_UT = (-0.31, 0.0, 0.37)  # the firmware's model of the field less the field, NED, µT

    def __init__(self, *args: Any, firmware: str = "1.15.0", autocal_after_s: float = 30.0,
                 autosave_interval_s: float = 2.0, shell: bool = True, preset_ids: bool = False,
                 untagged: bool = False, model_field_offset_ut: tuple[float, float, float] | None = None,
                 **kwargs: Any) -> None:
        self.shell = shell  # False: the shell echoes each line and runs none (a POSIX build over MAVLink)
        self.preset_ids = preset_ids
        self.firmware_version = tuple(int(x) for x in firmware.split("."))[:3]  # type: ignore[assignment]
        # a build from an untagged tree (SITL, any developer's or custom build) says 0.0.0 in
        # AUTOPILOT_VERSION whatever parameters it has (docs/firmware.md, *Versions*)
        self.reported_version = (0, 0, 0) if untagged else self.firmware_version
        self.autocal_after_s = autocal_after_s
        # the firmware's model of the site's field less the field (NED, µT): what EKF2's bias estimate learns
        self.model_field_offset_ut = np.asarray(model_field_offset_ut or self.MODEL_FIELD_OFFSET_UT, float)
        self.autosave_interval_s = autosave_interval_s  # PX4: 2 s; a test may stretch it
        self._save_due: float | None = None
        self._last_save = -1e9
        self._saving: tuple[float, dict[str, ParamValue]] | None = None  # (finishes at, snapshot)
        self._shell_line = b""
        self._gyro_cal_done_at: float | None = None  # the commander's gyro calibration in progress
        self._worker_save: float | None = None  # a forced save on the worker thread ends then
        self._worker_free_at = 0.0  # the worker thread takes a new task from then on
        super().__init__(*args, **kwargs)

    @property
    def has_odiag(self) -> bool:
        return self.firmware_version >= (1, 12, 0)

    @property
    def has_euler(self) -> bool:
        return self.firmware_version >= (1, 15, 0)

    def param_specs(self) -> list[ParamSpec]:
        specs = [s for n in range(SLOTS) for s in slot_params(n, self.has_odiag, self.has_euler)]
        specs += [ParamSpec("CAL_MAG_COMP_TYP", INT32, 0), ParamSpec("CAL_MAG_SIDES", INT32, 63),
                  ParamSpec("SENS_MAG_AUTOCAL", INT32, 1), ParamSpec("SENS_MAG_AUTOROT", INT32, 1),
                  ParamSpec("SENS_MAG_MODE", INT32, 1), ParamSpec("SENS_MAG_RATE", REAL32, 15.0),
                  ParamSpec("SENS_MAG_SIDES", INT32, 63), ParamSpec("SENS_BOARD_ROT", INT32, 0),
                  *(ParamSpec(f"SENS_BOARD_{a}_OFF", REAL32, 0.0) for a in AXES),
                  ParamSpec("MBE_ENABLE", INT32, 1), ParamSpec("SYS_FAC_CAL_MODE", INT32, 0),
                  ParamSpec("SYS_AUTOSTART", INT32, 4001), ParamSpec("MAV_SYS_ID", INT32, 1),
                  ParamSpec("CAL_GYRO0_ID", INT32, 2293768), ParamSpec("CAL_GYRO0_PRIO", INT32, -1),
                  *(ParamSpec(f"CAL_GYRO0_{a}OFF", REAL32, 0.0) for a in AXES)]
        return [spec for spec in specs if spec.name not in self.faults.unknown_params]

    # ------------------------------------------------------------------ parameters
    def wire_value(self, spec: ParamSpec, value: ParamValue) -> float:
        return bytewise_to_wire(value, spec.type)

    def handle_param_set(self, msg: Any) -> None:
        name = msg.param_id
        spec = self.table.specs.get(name)
        if spec is None or msg.param_type != spec.type or self.faults.ignores(name):
            return  # PX4 1.13–1.16: console error only, no reply
        value = bytewise_from_wire(msg.param_value, spec.type)
        if not spec.is_int and not np.isfinite(value):
            return
        if self.table.set(name, value) and self._save_due is None:
            self._save_due = max(time.monotonic() + self.AUTOSAVE_DELAY_S, self._last_save + self.autosave_interval_s)
        if name not in self.faults.lose_param_echo:
            self.send_param(name)

    def load_from_storage(self, stored: dict[str, ParamValue]) -> None:
        if self.preset_ids:  # the startup script's set-default: each detected sensor's id in its slot
            for n, sensor in enumerate(self.detected[:SLOTS]):
                name = f"CAL_MAG{n}_ID"
                self.table.specs[name] = replace(self.table.specs[name], default=sensor.device_id)
        # rcS: the factory store first (``param load /fs/mtd_caldata`` where the board has the partition),
        # then the user's file over it: a calibration parameter the user's file does not hold (never set,
        # or reset) keeps its factory value
        self.table.load({**self.factory_store(), **stored})
        self._save_due = None
        self._saving = None
        self._shell_line = b""
        self._gyro_cal_done_at = None
        self._worker_save = None
        self._worker_free_at = 0.0

    def _start_save(self, now: float) -> None:
        self._saving = (now + self.save_duration_s, self.table.non_default())
        self._last_save = now

    # ------------------------------------------------------------------ factory calibration storage
    @property
    def factory_path(self):
        return self.workdir / "px4-mtd_caldata.json"

    def factory_store(self) -> dict[str, ParamValue]:
        """What ``/fs/mtd_caldata`` holds (nothing on a board without the partition)."""
        from magline.sim.storage import NvStorage

        return {} if self.faults.no_factory_partition else NvStorage(self.factory_path).load()

    def _exported(self, mode: int) -> dict[str, ParamValue]:
        """``filter_calibration_params`` over the parameters set (PX4 exports its user config)."""
        def kept(name: str) -> bool:
            if mode == 2 and name.startswith("CAL_MAG"):
                return False
            return (name.startswith("CAL_") and name != "CAL_MAG_SIDES" and not name.endswith("_PRIO")) \
                or name.startswith("TC_")

        return {n: v for n, v in self.table.non_default().items() if kept(n)}

    def _calibrate(self, params: list[float]) -> int:
        """MAV_CMD_PREFLIGHT_CALIBRATION: only the gyro (param1 = 1) is simulated; accepted at once, the
        result in STATUSTEXT when it ends, as the commander's worker thread does."""
        if int(params[0]) != 1 or any(int(p) for p in params[1:6]):
            return UNSUPPORTED
        if self._worker_busy(time.monotonic()):
            return mavlink.MAV_RESULT_TEMPORARILY_REJECTED
        self.statustext(mavlink.MAV_SEVERITY_INFO, CAL_STARTED.format("gyro"))
        self._gyro_cal_done_at = time.monotonic() + GYRO_CAL_S / max(1.0, self.motion_speed())
        return ACCEPTED

    def _worker_busy(self, now: float) -> bool:
        """Whether the commander's worker thread refuses a new task now."""
        return self._gyro_cal_done_at is not None or self._worker_save is not None or now < self._worker_free_at

    def _finish_gyro_calibration(self) -> None:
        """``do_gyro_calibration``: motion fails it; the factory store is opened (its partition must be
        there) whenever SYS_FAC_CAL_MODE ≥ 1, and written after the gyro's parameters."""
        self._gyro_cal_done_at = None
        self._worker_free_at = time.monotonic() + WORKER_REAP_S
        mode = int(self.table.values.get("SYS_FAC_CAL_MODE", 0))
        ok = True
        if self.faults.moved_during_gyro_cal:
            self.statustext(mavlink.MAV_SEVERITY_CRITICAL, "ERROR: Motion during calibration")
            ok = False
        if mode >= 1 and self.faults.no_factory_partition:
            self.statustext(mavlink.MAV_SEVERITY_CRITICAL, "ERROR: cannot open calibration storage")
            ok = False
        if ok:
            for axis, offset in zip(AXES, self.rng.normal(0.0, 0.002, 3), strict=True):
                self.table.set(f"CAL_GYRO0_{axis}OFF", float(offset))
            if mode >= 1 and self.faults.factory_store_fails:
                ok = False  # "param export failed": on the console only
            elif mode >= 1 and not self.faults.factory_store_stale:
                from magline.sim.storage import NvStorage

                NvStorage(self.factory_path).save(self._exported(mode))
            self._save_due = self._save_due or time.monotonic() + self.AUTOSAVE_DELAY_S
        self.statustext(mavlink.MAV_SEVERITY_INFO if ok else mavlink.MAV_SEVERITY_CRITICAL,
                        (CAL_DONE if ok else CAL_FAILED).format("gyro"))

    def tick(self, now: float) -> None:
        if self._gyro_cal_done_at is not None and now >= self._gyro_cal_done_at and self.power is Power.UP:
            self._finish_gyro_calibration()
        if self._worker_save is not None and now >= self._worker_save:
            self._worker_save = None
            self._worker_free_at = now + WORKER_REAP_S
        if self._saving is not None and now >= self._saving[0]:
            self.write_storage(self._saving[1])
            self._saving = None
        if self._save_due is not None and now >= self._save_due and self._saving is None:
            self._save_due = None
            self._start_save(now)
        if self.power is Power.UP:
            self._autocal(now)

    def on_power_loss(self) -> None:
        self._saving = None  # a save cut by the power never reaches storage
        self._save_due = None

    def shutdown_ready(self, now: float) -> bool:
        return self._saving is None  # the reboot waits for the shutdown lock a save holds

    # ------------------------------------------------------------------ calibration as the firmware applies it
    def slot_of(self, device_id: int) -> int | None:
        for n in range(SLOTS):
            if self.table.values[f"CAL_MAG{n}_ID"] == device_id:
                return n
        return None

    def calibration(self, n: int) -> tuple[NDArray, NDArray]:
        """(offset in Gauss, scale matrix) held in slot n."""
        v = self.table.values
        p = f"CAL_MAG{n}_"
        off = np.array([v[f"{p}{a}OFF"] for a in AXES])
        s = np.diag([v[f"{p}{a}SCALE"] for a in AXES])
        if self.has_odiag:
            s[0, 1] = s[1, 0] = v[p + "XODIAG"]
            s[0, 2] = s[2, 0] = v[p + "YODIAG"]
            s[1, 2] = s[2, 1] = v[p + "ZODIAG"]
        return off, s

    def corrected_ut(self, sensor: SimMagnetometer, raw_ut: NDArray) -> NDArray:
        n = self.slot_of(sensor.device_id)
        applied = self.faults.cal_applied
        if n is None or applied == "none":
            return raw_ut  # no matching slot: calibration reset, raw data used (fault: never applied)
        if applied == "slot":
            n = (n + 1) % SLOTS  # fault: the next slot's calibration
        off_g, s = self.calibration(n)
        off_g = {"sign": -off_g, "unit": off_g / 1000.0}.get(applied, off_g)  # faults: read another way
        return self.rotation(n, sensor) @ s @ (raw_ut / 100.0 + self.power_compensation_g(n) - off_g) * 100.0

    def power_compensation_g(self, n: int) -> NDArray:
        """``power · CAL_MAGn_xCOMP`` of Magnetometer::Correct (G), added to the raw reading before the
        offset: with CAL_MAG_COMP_TYP 2 or 3, power is the battery current in kA.  A BATTERY_STATUS lands in
        instance 0 whatever its id, and type 3 without an instance 1 keeps compensating from instance 0
        (docs/firmware.md, *Current interference*): both read the board's one current.  Throttle mode (1)
        applies only when armed."""
        v = self.table.values
        if int(v["CAL_MAG_COMP_TYP"]) not in (2, 3):
            return np.zeros(3)
        return np.array([v[f"CAL_MAG{n}_{a}COMP"] for a in AXES]) * self.firmware_current_a() / 1000.0

    def rotation(self, n: int, sensor: SimMagnetometer) -> NDArray:
        """R of ``R·S·(raw − OFF)``: the board's level adjustment (SENS_BOARD_X/Y/Z_OFF: roll, pitch, yaw
        in degrees, applied to external sensors too) times the sensor's rotation: an external sensor's
        CAL_MAGn_ROT (the custom Euler angles for 100, none for −1), an internal one the board's
        (SENS_BOARD_ROT)."""
        v = self.table.values
        level = Rotation.from_euler("ZYX", [v[f"SENS_BOARD_{a}_OFF"] for a in "ZYX"], degrees=True).as_matrix()
        return level @ self._sensor_rotation(n, sensor)

    def _sensor_rotation(self, n: int, sensor: SimMagnetometer) -> NDArray:
        v = self.table.values
        p = f"CAL_MAG{n}_"
        if not sensor.external:
            return orientation_matrix(int(v["SENS_BOARD_ROT"]))
        rot = int(v[p + "ROT"])
        if rot == 100 and self.has_euler:
            return Rotation.from_euler("ZYX", [v[p + "YAW"], v[p + "PITCH"], v[p + "ROLL"]], degrees=True).as_matrix()
        return orientation_matrix(rot) if rot >= 0 else np.eye(3)

    def _autocal(self, now: float) -> None:
        """SENS_MAG_AUTOCAL: an uncalibrated sensor gets the firmware's own offset estimate."""
        if self.table.values["SENS_MAG_AUTOCAL"] != 1 or now - self._booted_at < self.autocal_after_s:
            return
        for sensor in self.detected:
            if self.slot_of(sensor.device_id) is not None:
                continue
            free = self.slot_of(0)
            if free is None:
                return
            p = f"CAL_MAG{free}_"
            self.table.set(p + "ID", sensor.device_id)
            self.table.set(p + "PRIO", 75 if sensor.external else 50)
            for axis, h in zip(AXES, sensor.hard_iron_ut, strict=True):
                self.table.set(f"{p}{axis}OFF", round(h / 100.0, 2))  # a coarse online estimate
            if self._save_due is None:
                self._save_due = max(now + self.AUTOSAVE_DELAY_S, self._last_save + self.autosave_interval_s)

    # ------------------------------------------------------------------ streams
    # SCALED_IMU carries the IMU's time stamp with the latest sensor_mag, measured 28–36 ms older on
    # PX4 v1.16 SITL against an analytic truth (issue 50; 12–32 ms on an older build, docs/firmware.md, *Timing*)
    MAG_AGE_S = (0.028, 0.036)

    def mag_age_s(self) -> float:
        return float(self.rng.uniform(*self.MAG_AGE_S))

    def stream_message(self, msg_id: int, now: float) -> Any | None:
        reading = self.raw_reading_ut(self.stream_sensor[msg_id], now)
        if reading is None:
            return None
        sensor, raw_ut = reading
        acc = self.accel_mg(now)
        t_ms = self.time_boot_ms(now)
        if msg_id == mavlink.MAVLINK_MSG_ID_HIGHRES_IMU:
            # stamped with the IMU sample's own time in microseconds (HIGHRES_IMU.hpp: time_usec =
            # vehicle_imu.timestamp_sample), not the millisecond of the SCALED_IMU messages
            cal_g = (self.corrected_ut(sensor, raw_ut) - self.estimated_bias_ut(now)) / 100.0
            return self.mav.highres_imu_encode(self.time_boot_us(now), *(acc * 9.80665e-3), 0.0, 0.0, 0.0, *cal_g,
                                               1013.25, 0.0, 0.0, 25.0, 0x1FF)
        encode = {mavlink.MAVLINK_MSG_ID_SCALED_IMU: self.mav.scaled_imu_encode,
                  mavlink.MAVLINK_MSG_ID_SCALED_IMU2: self.mav.scaled_imu2_encode,
                  mavlink.MAVLINK_MSG_ID_SCALED_IMU3: self.mav.scaled_imu3_encode}[msg_id]
        return encode(t_ms, *acc.astype(int), 0, 0, 0, *int16_mg(raw_ut * 10.0), 2500)

    # PX4 streams EXTENDED_SYS_STATE (src/modules/mavlink/streams/EXTENDED_SYS_STATE.hpp), which MAVSDK asks for
    # at every connection: refused, its FAILED acknowledgement could be taken for the answer to the station's own
    # SET_MESSAGE_INTERVAL waiting at that moment (MAVSDK matches an acknowledgement by its command alone)
    STATUS_MESSAGES = (*SimulatedAutopilot.STATUS_MESSAGES, mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE)

    def send_status(self, msg_id: int, now: float) -> None:
        if msg_id == mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE:  # a multicopter on the bench
            self.mav.extended_sys_state_send(mavlink.MAV_VTOL_STATE_UNDEFINED, mavlink.MAV_LANDED_STATE_ON_GROUND)
            return
        super().send_status(msg_id, now)

    def estimated_bias_ut(self, now: float) -> NDArray:
        """EKF2's magnetometer bias estimate at ``now`` (µT, body axes): the field less the firmware's model
        of it, in the unit's attitude now."""
        return self.ned_to_body(now) @ -np.asarray(self.model_field_offset_ut, float)

    # ------------------------------------------------------------------ commands
    def extra_commands(self) -> dict:
        return {mavlink.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN: self._reboot,
                mavlink.MAV_CMD_PREFLIGHT_STORAGE: self._storage,
                mavlink.MAV_CMD_PREFLIGHT_CALIBRATION: self._calibrate}

    def _reboot(self, params: list[float]) -> int:
        action = int(params[0])
        if action == 0:
            return ACCEPTED
        if action in (1, 3):
            self.request_reboot(self.REBOOT_DELAY_S)
            return ACCEPTED
        if action == 2:
            self.after_ack(self.power_off)  # shutdown: stays off until power is applied again
            return ACCEPTED
        return DENIED

    def _storage(self, params: list[float]) -> int:
        action = int(params[0])
        if self._worker_busy(time.monotonic()):
            return mavlink.MAV_RESULT_TEMPORARILY_REJECTED
        if action == 0:
            self.load_from_storage(self.read_storage())
            return ACCEPTED
        if action == 1:
            self._worker_save = time.monotonic() + self.save_duration_s
            self.after_ack(lambda: self._start_save(time.monotonic()))  # ACK first, save on the worker
            return ACCEPTED
        if action == 3:  # ParamResetSensorFactory: CAL_ACC*, CAL_GYRO*, CAL_MAG* reset, saved, rebooted
            for name in self.table.names:
                if name.startswith(("CAL_ACC", "CAL_GYRO", "CAL_MAG")):
                    self.table.set(name, self.table.specs[name].default)
            self._start_save(time.monotonic())
            self.request_reboot(self.REBOOT_DELAY_S)
            return ACCEPTED
        return UNSUPPORTED

    # ------------------------------------------------------------------ MAVLink shell
    def handle_other(self, msg: Any) -> None:
        if msg.get_type() != "SERIAL_CONTROL" or msg.device != SHELL_DEVICE:
            return
        self._shell_line += bytes(msg.data[: msg.count])
        while b"\n" in self._shell_line:
            line, _, self._shell_line = self._shell_line.partition(b"\n")
            if self.shell:
                self._shell_reply(self._shell(line.decode(errors="replace").strip()))
            else:  # a POSIX build's shell echoes the line and runs nothing (seen on PX4 SITL)
                self._shell_send(line + b"\n")

    def _shell(self, line: str) -> str:
        words = line.split()
        if not words:
            return ""
        if words[:2] == ["listener", "sensor_mag"]:
            instance = int(words[words.index("-i") + 1]) if "-i" in words else 0
            if instance >= len(self.detected):
                return "never published\n"
            sensor = self.detected[instance]
            raw = sensor.read_ut(self.body_field_ut(time.monotonic()), self.rng) / 100.0
            ts = self.time_boot_ms(time.monotonic()) * 1000
            return (f"\nTOPIC: sensor_mag instance {instance}\n sensor_mag\n    timestamp: {ts}\n"
                    f"    timestamp_sample: {ts - 250}\n    device_id: {sensor.device_id} "
                    f"(Type: 0x{sensor.device_id >> 16 & 0xFF:02X}, bus {sensor.device_id >> 3 & 0x1F})\n"
                    f"    x: {raw[0]:.5f}\n    y: {raw[1]:.5f}\n    z: {raw[2]:.5f}\n    temperature: 25.00000\n"
                    f"    error_count: 0\n    is_external: {sensor.external}\n")
        if words == ["bsondump", FACTORY_STORE]:
            if self.faults.no_factory_partition or not self.factory_path.exists():
                return f"ERROR [bsondump] open '{FACTORY_STORE}' failed (2)\n"
            rows = [f"BSON_INT32:  {n} = {int(v)}" if self.table.specs[n].is_int else f"BSON_DOUBLE: {n} = {v:.6f}"
                    for n, v in sorted(self.factory_store().items()) if n in self.table.specs]
            return "\n".join([*rows, "BSON_EOO"]) + "\n"
        return f"nsh: {words[0]}: command not found\n"

    def _shell_reply(self, text: str) -> None:
        self._shell_send((text + "nsh> ").encode())

    def _shell_send(self, data: bytes) -> None:
        for start in range(0, len(data), 70):
            chunk = data[start:start + 70]
            self.mav.serial_control_send(SHELL_DEVICE, SHELL_REPLY, 0, 0, len(chunk), list(chunk.ljust(70, b"\0")))
