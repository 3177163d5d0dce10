"""A simulated ArduPilot flight controller (behaviour per ``docs/firmware.md``, *ArduPilot*).

What it reproduces, because each is a trap for a factory tool:
- PARAM_SET is C-cast (``float(value)``), the type field is ignored, unknown names, NaN and
  infinity are ignored without a reply; a set of one element of a vector parameter is answered
  with all three; the value reaches storage before the echo is sent;
- compass sets are reordered at boot so set i holds the sensor named by ``COMPASS_PRIO{i+1}_ID``,
  and the detected ids appear in ``COMPASS_DEV_ID*`` in RAM only;
- a compass counts as calibrated only if its offsets are non-zero and its DEV_ID was *saved*
  (MAV_CMD_PREFLIGHT_CALIBRATION param2 = 76); MAV_CMD_RUN_PREARM_CHECKS reports it;
- RAW_IMU / SCALED_IMU2 / SCALED_IMU3 carry the *corrected* body-frame field in mG (offsets added,
  SCALE, then the DIA/ODI matrix), so raw data needs the calibration neutralised or inverted; the
  int16 fields are filled by a C conversion (truncation toward zero, not rounding);
- the compass is read at 10 Hz (ArduCopter's scheduler) while a stream goes out at the rate asked
  for, so RAW_IMU at 50 Hz carries each reading about five times;
- a reboot closes the TCP connection; the client must reconnect;
- ``COMPASS_ORIENTn`` is applied to an external compass only, before the offsets, so the streamed
  field is in body axes; a sensor is mounted as SITL's ``SIM_MAGn_ORIENT`` (``mounting``) and the
  value that corrects it is that same number; SCALED_IMU3's accelerometer fields are all zero;
- MAV_CMD_RUN_PREARM_CHECKS also reports "Compasses inconsistent" when a used compass disagrees with
  the primary beyond AP_Compass's limits (an uncalibrated second compass does).
"""

from __future__ import annotations

import functools
import time
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from magline.core.mounting import orientation_matrix
from magline.sim.magnetometers import SimMagnetometer, driver_rate_hz
from magline.sim.params import INT8, INT16, INT32, REAL32, ParamSpec, ParamValue, ccast_from_wire
from magline.sim.vehicle import ACCEPTED, UNSUPPORTED, SimulatedAutopilot, int16_mg

SETS = ("", "2", "3")
AXES = ("X", "Y", "Z")
MOTCT_CURRENT = 2  # COMPASS_MOTCT: 0 off, 1 throttle, 2 current
MAX_SCALE_FACTOR = 1.5
FIELD_MG_LIMITS = (185.0, 875.0)
MAX_XYZ_ANGLE_DEG, MAX_XY_ANGLE_DEG, MAX_XY_LENGTH_MG = 90.0, 60.0, 200.0  # AP_Compass consistency limits


@functools.cache
def set_names(suffix: str) -> dict[str, list[str] | str]:
    """Parameter names of one compass set (``""``, ``"2"``, ``"3"``); made once per set (asked at every
    streamed message), not to be changed by its callers."""
    ext = "EXTERNAL" if suffix == "" else f"EXTERN{suffix}"
    return {"OFS": [f"COMPASS_OFS{suffix}_{a}" for a in AXES], "DIA": [f"COMPASS_DIA{suffix}_{a}" for a in AXES],
            "ODI": [f"COMPASS_ODI{suffix}_{a}" for a in AXES], "MOT": [f"COMPASS_MOT{suffix}_{a}" for a in AXES],
            "SCALE": f"COMPASS_SCALE{suffix}", "DEV_ID": f"COMPASS_DEV_ID{suffix}",
            "ORIENT": f"COMPASS_ORIENT{suffix}", "EXTERNAL": f"COMPASS_{ext}", "USE": f"COMPASS_USE{suffix}"}


def _set_specs(suffix: str) -> list[ParamSpec]:
    n = set_names(suffix)
    specs = [ParamSpec(x, REAL32, 0.0) for x in n["OFS"]] + [ParamSpec(x, REAL32, 1.0) for x in n["DIA"]]
    specs += [ParamSpec(x, REAL32, 0.0) for x in n["ODI"]] + [ParamSpec(x, REAL32, 0.0) for x in n["MOT"]]
    specs += [ParamSpec(n["SCALE"], REAL32, 0.0), ParamSpec(n["DEV_ID"], INT32, 0),
              ParamSpec(n["ORIENT"], INT8, 0), ParamSpec(n["EXTERNAL"], INT8, 0), ParamSpec(n["USE"], INT8, 1)]
    return specs


class ArduPilotSim(SimulatedAutopilot):
    flavour = "ardupilot"
    autopilot = mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
    capabilities = (mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST
                    | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                    | mavlink.MAV_PROTOCOL_CAPABILITY_COMPASS_CALIBRATION | mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2)
    default_listen = "tcp:127.0.0.1:5760"
    storage_name = "eeprom.json"
    firmware_version = (4, 6, 2)
    ANSWERS_WITH_ASKED_INDEX = True
    # compass priority 0/1/2 → RAW_IMU (and SCALED_IMU, same numbers) / SCALED_IMU2 / SCALED_IMU3
    stream_sensor: ClassVar[dict[int, int]] = {mavlink.MAVLINK_MSG_ID_RAW_IMU: 0, mavlink.MAVLINK_MSG_ID_SCALED_IMU: 0,
                     mavlink.MAVLINK_MSG_ID_SCALED_IMU2: 1, mavlink.MAVLINK_MSG_ID_SCALED_IMU3: 2}
    REBOOT_DELAY_S = 0.2
    # ArduCopter's motor_test.cpp (mavlink_motor_control_check): "%s: RC not calibrated" with "Motor Test"
    MOTOR_TEST_REFUSAL = "Motor Test: RC not calibrated"
    firmware_mag_rate_hz: ClassVar[float | None] = 10.0  # ArduCopter's update_compass task

    def samples_per_reading(self, sensor: SimMagnetometer) -> int:
        """ArduPilot's drivers accumulate every sample they read (``AP_Compass_Backend::accumulate_sample``)
        and the compass's read drains the sum as its mean (``drain_accumulated_samples``): a reading
        published at ArduCopter's 10 Hz is the mean of the driver's samples since the last one — its noise
        the sample's over √(driver rate / 10).  Centred on the reading's time: the 40 ms between
        accelerometer and compass measured on SITL (``ACCEL_AGE_S``) was measured on such means."""
        return max(1, round(driver_rate_hz(sensor.device_id) / self.sensor_rate_hz(sensor)))

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.stored: dict[str, ParamValue] = {}
        self.sets: list[SimMagnetometer | None] = [None, None, None]  # sensor behind each set after boot
        self._corrections: dict[int, tuple] = {}  # set index → (its parameters, its correction as arrays)
        super().__init__(*args, **kwargs)

    def param_specs(self) -> list[ParamSpec]:
        specs = [s for suffix in SETS for s in _set_specs(suffix)]
        specs += [ParamSpec(f"COMPASS_PRIO{i}_ID", INT32, 0) for i in (1, 2, 3)]
        specs += [ParamSpec(f"COMPASS_DEV_ID{i}", INT32, 0, read_only=True) for i in range(4, 9)]
        specs += [ParamSpec("COMPASS_ENABLE", INT8, 1), ParamSpec("COMPASS_LEARN", INT8, 0),
                  ParamSpec("COMPASS_MOTCT", INT8, 0), ParamSpec("COMPASS_OFFS_MAX", INT16, 1800),
                  ParamSpec("COMPASS_CAL_FIT", REAL32, 16.0), ParamSpec("COMPASS_AUTO_ROT", INT8, 2),
                  ParamSpec("AHRS_ORIENTATION", INT8, 0), ParamSpec("SYSID_THISMAV", INT16, 1)]
        return specs

    # ------------------------------------------------------------------ parameters
    def wire_value(self, spec: ParamSpec, value: ParamValue) -> float:
        return float(value)

    def handle_param_set(self, msg: Any) -> None:
        name = msg.param_id
        spec = self.table.specs.get(name)
        if spec is None or self.faults.ignores(name):
            return
        value = ccast_from_wire(msg.param_value, spec.type)  # param_type is ignored
        if value is None:
            return
        if spec.read_only:
            self.statustext(mavlink.MAV_SEVERITY_WARNING, "Param write denied")
            self.send_param(name, -1)
            return
        self.table.set(name, value)
        self._store(name)
        for sibling in self._vector_of(name):
            if not (sibling == name and name in self.faults.lose_param_echo):
                self.send_param(sibling, -1)

    @staticmethod
    def _vector_of(name: str) -> list[str]:
        if name[-2:] in ("_X", "_Y", "_Z") and name.startswith("COMPASS_"):
            return [name[:-1] + a for a in AXES]
        return [name]

    def _store(self, name: str) -> None:
        """AP_Param keeps a record only for values that differ from the default."""
        if name in self.faults.no_persist:
            return
        value = self.table.values[name]
        if value == self.table.specs[name].default:
            self.stored.pop(name, None)
        else:
            self.stored[name] = value
        self.write_storage(self.stored)

    def load_from_storage(self, stored: dict[str, ParamValue]) -> None:
        self.stored = dict(stored)
        self.table.load(stored)
        self._reorder_sets()

    def _reorder_sets(self) -> None:
        """Boot: swap whole sets so set i is COMPASS_PRIO{i+1}_ID, then detect sensors into them."""
        v = self.table.values
        names = [set_names(s) for s in SETS]
        for i in range(3):
            want = v[f"COMPASS_PRIO{i + 1}_ID"]
            if not want or v[names[i]["DEV_ID"]] == want:
                continue
            j = next((k for k in range(3) if v[names[k]["DEV_ID"]] == want), None)
            if j is not None:
                self._swap(names[i], names[j])
        prio = [v[f"COMPASS_PRIO{i}_ID"] for i in (1, 2, 3)]
        remaining = [m for m in self.detected if m.device_id not in prio]
        self.sets = []
        for i in range(3):
            sensor = next((m for m in self.detected if prio[i] and m.device_id == prio[i]), None)
            if sensor is None and not prio[i] and remaining:
                sensor = remaining.pop(0)
            self.sets.append(sensor)
            v[names[i]["DEV_ID"]] = sensor.device_id if sensor else 0  # RAM only
            if not prio[i] and sensor is not None:
                v[f"COMPASS_PRIO{i + 1}_ID"] = sensor.device_id  # set automatically, RAM only

    def _swap(self, a: dict, b: dict) -> None:
        v = self.table.values
        for key in ("OFS", "DIA", "ODI", "MOT"):
            for x, y in zip(a[key], b[key], strict=True):
                v[x], v[y] = v[y], v[x]
        for key in ("SCALE", "DEV_ID", "ORIENT", "EXTERNAL"):
            v[a[key]], v[b[key]] = v[b[key]], v[a[key]]

    def _force_save_calibration(self) -> None:
        """MAV_CMD_PREFLIGHT_CALIBRATION param2 = 76: save every non-zero DEV_ID (and the priorities)."""
        for suffix in SETS:
            self._store(set_names(suffix)["DEV_ID"])
        for i in (1, 2, 3):
            self._store(f"COMPASS_PRIO{i}_ID")

    # ------------------------------------------------------------------ calibration as the firmware applies it
    def set_index(self, sensor: SimMagnetometer) -> int | None:
        return next((i for i, m in enumerate(self.sets) if m is sensor), None)

    def corrected_ut(self, sensor: SimMagnetometer, raw_ut: NDArray) -> NDArray:
        i = self.set_index(sensor)
        if i is None:
            return raw_ut
        return self.correct_mg(i, raw_ut * 10.0) / 10.0

    def external(self, i: int) -> bool:
        """An external compass (its driver says so, or ``COMPASS_EXTERNn`` forces it)."""
        sensor = self.sets[i]
        return bool(self.table.values[set_names(SETS[i])["EXTERNAL"]]) or bool(sensor is not None and sensor.external)

    def orientation(self, i: int) -> NDArray:
        """``COMPASS_ORIENTn`` applies to an external compass only (AP_Compass_Backend); an internal one
        follows the board (AHRS_ORIENTATION, identity here)."""
        if not self.external(i):
            return np.eye(3)
        return orientation_matrix(int(self.table.values[set_names(SETS[i])["ORIENT"]]))

    def correct_mg(self, i: int, raw_mg: NDArray) -> NDArray:
        """rotate (COMPASS_ORIENTn, external only) → add OFS → SCALE if valid → DIA/ODI matrix unless all DIA are 0."""
        rotation, offsets, scale, matrix, motor = self._correction(i)
        out = rotation @ raw_mg + offsets
        if scale is not None:
            out = out * scale
        if matrix is not None:
            out = matrix @ out
        if motor is not None:
            # AP_Compass_Backend::correct_field: after the matrix, in the rotated frame, MOT (mG/A) times the
            # primary battery monitor's current is *added* (docs/firmware.md, *Current interference*); no armed
            # check in current mode
            out = out + motor * self.firmware_current_a()
        return out

    def _correction(self, i: int) -> tuple[NDArray, NDArray, float | None, NDArray | None, NDArray | None]:
        """The set's correction as arrays (rotation, offsets, a valid scale, the DIA/ODI matrix, MOT in current
        mode), made again only when one of its parameters changed.  Why: every streamed message is corrected,
        three compasses at 200 Hz in the tests, and building the arrays from the parameters took most of it."""
        v = self.table.values
        n = set_names(SETS[i])
        sensor = self.sets[i] if i < len(self.sets) else None  # named by its id (its dataclass == compares arrays)
        key = (None if sensor is None else (sensor.device_id, sensor.external), tuple(v[x] for x in n["OFS"]),
               v[n["SCALE"]], tuple(v[x] for x in n["DIA"]), tuple(v[x] for x in n["ODI"]), v[n["ORIENT"]],
               v[n["EXTERNAL"]], int(v["COMPASS_MOTCT"]), tuple(v[x] for x in n["MOT"]))
        cached = self._corrections.get(i)
        if cached is not None and cached[0] == key:
            return cached[1]
        _, ofs, scale, dia, odi, _, _, motct, mot = key
        matrix = None
        if any(dia):
            matrix = np.array([[dia[0], odi[0], odi[1]], [odi[0], dia[1], odi[2]], [odi[1], odi[2], dia[2]]])
        made = (self.orientation(i), np.array(ofs), scale if 1.0 / MAX_SCALE_FACTOR <= scale <= MAX_SCALE_FACTOR
                else None, matrix, np.array(mot) if motct == MOTCT_CURRENT else None)
        self._corrections[i] = (key, made)
        return made

    def configured(self, i: int) -> bool:
        """Compass::configured: non-zero offsets and the *stored* DEV_ID equals the detected one."""
        n = set_names(SETS[i])
        sensor = self.sets[i]
        ofs = [self.table.values[x] for x in n["OFS"]]
        return sensor is not None and any(ofs) and self.stored.get(n["DEV_ID"]) == sensor.device_id

    # ------------------------------------------------------------------ streams
    # On ArduCopter SITL the compass readings fit best placed about 40 ms after the RAW_IMU they first
    # appear in (issue 50): the accelerometer in the message is that much older than the compass
    ACCEL_AGE_S = 0.040

    def accel_age_s(self) -> float:
        return self.ACCEL_AGE_S

    def stream_message(self, msg_id: int, now: float) -> Any | None:
        i = self.stream_sensor[msg_id]
        sensor = self.sets[i] if i < len(self.sets) else None
        if sensor is None:
            return None
        raw_ut = self.held_reading_ut(sensor, now)
        mag = int16_mg(self.correct_mg(i, raw_ut * 10.0))
        # SITL has two IMUs: SCALED_IMU3's accelerometer fields are all zero (docs/firmware.md, *SITL*)
        acc = self.accel_mg(now).astype(int) if msg_id != mavlink.MAVLINK_MSG_ID_SCALED_IMU3 else np.zeros(3, int)
        t_ms = self.time_boot_ms(now)
        if msg_id == mavlink.MAVLINK_MSG_ID_RAW_IMU:
            return self.mav.raw_imu_encode(t_ms * 1000, *acc, 0, 0, 0, *mag, 0, 2500)
        encode = {mavlink.MAVLINK_MSG_ID_SCALED_IMU: self.mav.scaled_imu_encode,
                  mavlink.MAVLINK_MSG_ID_SCALED_IMU2: self.mav.scaled_imu2_encode,
                  mavlink.MAVLINK_MSG_ID_SCALED_IMU3: self.mav.scaled_imu3_encode}[msg_id]
        return encode(t_ms, *acc, 0, 0, 0, *mag, 2500)

    # ------------------------------------------------------------------ commands
    def extra_commands(self) -> dict:
        return {mavlink.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN: self._reboot,
                mavlink.MAV_CMD_PREFLIGHT_CALIBRATION: self._calibration,
                mavlink.MAV_CMD_RUN_PREARM_CHECKS: self._prearm}

    def _reboot(self, params: list[float]) -> int:
        if int(params[0]) not in (1, 3):
            return UNSUPPORTED
        self.request_reboot(self.REBOOT_DELAY_S)  # ACK first; storage is already written
        return ACCEPTED

    def _calibration(self, params: list[float]) -> int:
        if int(params[1]) == 76:
            self._force_save_calibration()
            return ACCEPTED
        return UNSUPPORTED

    def _prearm(self, params: list[float]) -> int:
        self.after_ack(self._report_prearm)
        return ACCEPTED

    def prearm_failures(self) -> list[str]:
        """The compass arming checks (AP_Arming): calibrated, offsets within OFFS_MAX, field strength."""
        out = []
        v = self.table.values
        for i, sensor in enumerate(self.sets):
            n = set_names(SETS[i])
            if sensor is None or not v[n["USE"]]:
                continue
            if not self.configured(i):
                out.append("Compass not calibrated")
                continue
            if np.linalg.norm([v[x] for x in n["OFS"]]) > v["COMPASS_OFFS_MAX"]:
                out.append("Compass offsets too high")
            field_mg = np.linalg.norm(self.correct_mg(i, sensor.read_ut(self.body_field_ut(0.0), self.rng) * 10.0))
            if not FIELD_MG_LIMITS[0] <= field_mg <= FIELD_MG_LIMITS[1]:
                out.append("Check mag field")
        if not self.consistent():
            out.append("Compasses inconsistent")
        return out

    def consistent(self) -> bool:
        """AP_Compass::consistent(): every used compass against the primary, in body axes — 3D angle
        ≤ 90°, horizontal angle ≤ 60°, horizontal length within 200 mG."""
        v = self.table.values
        used = [i for i, sensor in enumerate(self.sets)
                if sensor is not None and v[set_names(SETS[i])["USE"]]]
        if len(used) < 2:
            return True
        body = self.body_field_ut(time.monotonic())
        fields = {i: self.correct_mg(i, self.sets[i].read_ut(body, self.rng) * 10.0) for i in used}
        primary = fields[used[0]]
        for i in used[1:]:
            other = fields[i]
            angle = np.degrees(np.arccos(np.clip(primary @ other / np.linalg.norm(primary) / np.linalg.norm(other),
                                                 -1, 1)))
            xy_angle = abs((np.degrees(np.arctan2(other[1], other[0]) - np.arctan2(primary[1], primary[0])) + 180)
                           % 360 - 180)
            xy_length = abs(np.linalg.norm(other[:2]) - np.linalg.norm(primary[:2]))
            if angle > MAX_XYZ_ANGLE_DEG or xy_angle > MAX_XY_ANGLE_DEG or xy_length > MAX_XY_LENGTH_MG:
                return False
        return True

    def _report_prearm(self) -> None:
        for text in dict.fromkeys(self.prearm_failures()):
            self.statustext(mavlink.MAV_SEVERITY_CRITICAL, f"PreArm: {text}")
