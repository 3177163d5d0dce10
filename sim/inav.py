"""A simulated INAV flight controller speaking MSP (behaviour per ``docs/firmware.md``, *INAV*).

What it reproduces, because each is a trap for a station that calibrates over MSP:

- no raw magnetometer: ``MSP_RAW_IMU`` carries the field *calibrated and aligned*, per axis
  ``(raw − magzero)·1024/maggain`` in the sensor's counts (C integer division, truncating), then turned by
  ``align_mag`` — which the compass takes at boot only, DEFAULT meaning CW270FLIP — or, when any of
  ``align_mag_roll/pitch/yaw`` is set, by those angles instead (an external compass), and sent as int16;
  the accelerometer beside it in g·512 (+512 on Z when level); both in INAV's body axes, forward-left-up
  (``INAV_TO_FRD``: the engine's body and sensors are forward-right-down, INAV's y and z point the other way);
- settings by name with their own types and ranges (``MSP2_COMMON_SETTING_INFO``); a value is read in
  its setting's width, so one sent wider is stored truncated; out of range: an error reply;
- a written setting is used from the compass's next update, unsaved; ``MSP_EEPROM_WRITE`` saves all
  and reloads them (a stored ``align_mag`` of 0 comes back as 8); ``MSP_REBOOT`` re-executes the board,
  whose link drops and comes back; what was not saved is gone;
- while armed, ``MSP_EEPROM_WRITE`` gets an error reply and ``MSP_REBOOT`` an ACK and nothing more;
- the identity: ``MSP_FC_VARIANT`` "INAV", ``MSP_FC_VERSION``, ``MSP_BOARD_INFO``, ``MSP_UID``; the
  uptime in ``MSP2_INAV_MISC2``; the arming flags in ``MSP2_INAV_STATUS``.

Its one compass is a QMC5883L read at ±8 G (3000 counts per gauss, INAV's driver's range), mounted as
INAV's DEFAULT expects (CW270FLIP: Roll180Yaw90 in forward-right-down terms), updated at 10 Hz (INAV's
compass task) unless ``mag_rate_hz`` says.
"""

from __future__ import annotations

import struct
import time
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from magline.core.links.msp import (
    ERROR,
    INAV_ALIGNMENT_NAMES,
    INAV_ALIGNMENTS,
    INAV_ARMED_FLAG,
    INAV_COMPASS_DEFAULT_ALIGNMENT,
    INAV_TO_FRD,
    REPLY,
    REQUEST,
    SETTING_FORMATS,
    Msp,
    MspParser,
    SettingInfo,
    encode_msp_v1,
    encode_msp_v2,
    encode_setting_info,
    inav_external_rotation,
)
from magline.sim.magnetometers import SimMagnetometer
from magline.sim.params import INT16, UINT8, ParamSpec, ParamValue
from magline.sim.vehicle import Power, SimulatedAutopilot

INAV_UINT8, INAV_INT16 = 0, 3  # INAV's setting types (fc/settings.h)
COUNTS_PER_GAUSS = 3000.0  # QMC5883L at ±8 G
MAV_CW270FLIP = 10  # INAV's CW270FLIP as a MAV_SENSOR_ORIENTATION (Roll180Yaw90): how the compass sits
FLIP = np.array(INAV_TO_FRD, float)  # the engine's axes (forward-right-down) to INAV's (forward-left-up) and back
COMPASS_NOT_CALIBRATED = 1 << 12  # ARMING_DISABLED_COMPASS_NOT_CALIBRATED (fc/runtime_config.h)
NEW_TUMBLE_GAP_S = 1.0  # RAW_IMU unasked this long: the operator picks the unit up for another tumble
# … or asked again after the compass's calibration settings were written (the station sets the neutral
# calibration before each tumble): a fast station began the next unit within the gap, and the simulated unit,
# still resting where the last power cycle left it, never turned (coverage 0 %, three attempts)
CALIBRATION_SETTINGS = ("magzero_x", "magzero_y", "magzero_z", "maggain_x", "maggain_y", "maggain_z")


@dataclass(frozen=True)
class InavSetting:
    name: str
    type: int  # INAV's type code
    minimum: int
    maximum: int
    default: int
    names: tuple[str, ...] = ()  # a lookup setting's value names


SETTINGS = (
    InavSetting("align_mag", INAV_UINT8, 0, 8, 0, INAV_ALIGNMENT_NAMES),
    *(InavSetting(f"magzero_{a}", INAV_INT16, -32768, 32767, 0) for a in "xyz"),
    *(InavSetting(f"maggain_{a}", INAV_INT16, -32768, 32767, 1024) for a in "xyz"),
    InavSetting("mag_calibration_time", INAV_UINT8, 20, 120, 30),
    *(InavSetting(f"align_mag_{a}", INAV_INT16, -1800, 3600, 0) for a in ("roll", "pitch", "yaw")),
    InavSetting("mag_declination", INAV_INT16, -18000, 18000, 0),
)
MAV_TYPES = {INAV_UINT8: UINT8, INAV_INT16: INT16}


def inav_compass(rng: np.random.Generator) -> SimMagnetometer:
    """A board's compass with the per-axis distortion INAV can hold and the small cross terms a real one has
    (a unit with more is made on purpose: INAV's diagonal model then misfits it)."""
    cross = rng.uniform(-0.004, 0.004, size=3)
    soft = np.diag(np.exp(rng.uniform(-0.06, 0.06, size=3)))
    soft[0, 1] = soft[1, 0] = cross[0]
    soft[0, 2] = soft[2, 0] = cross[1]
    soft[1, 2] = soft[2, 1] = cross[2]
    return SimMagnetometer(device_id=1, hard_iron_ut=rng.uniform(-60, 60, size=3), soft_iron=soft, external=True)


class _NoMavlink:
    """INAV's MSP port carries no MAVLink: what the shared engine would send goes nowhere."""

    def write(self, data: bytes) -> None:
        return None


def truncating_div(a: int, b: int) -> int:
    """C's integer division (toward zero), as the firmware divides."""
    if b == 0:
        return 0
    q = abs(a) // abs(b)
    return q if (a >= 0) == (b > 0) else -q


def int16(value: int) -> int:
    """What ``sbufWriteU16`` makes of an int32: its low 16 bits, read back signed."""
    return struct.unpack("<h", struct.pack("<H", value & 0xFFFF))[0]


class InavSim(SimulatedAutopilot):
    flavour = "inav"
    autopilot = 0
    capabilities = 0
    default_listen = "tcp:127.0.0.1:5760"
    storage_name = "inav-eeprom.json"
    stream_sensor: ClassVar[dict[int, int]] = {}
    firmware_mag_rate_hz: ClassVar[float | None] = 10.0  # INAV's compass task
    firmware_version = (9, 1, 0)
    REBOOT_DELAY_S = 0.05
    BOARD = b"SITL"
    TARGET = b"SITL"

    def __init__(self, *args: Any, counts_per_gauss: float = COUNTS_PER_GAUSS, **kwargs: Any) -> None:
        self.counts_per_ut = counts_per_gauss / 100.0
        self.settings = {s.name: s for s in SETTINGS}
        if "magnetometers" not in kwargs:
            seed = kwargs.get("seed")
            kwargs["magnetometers"] = [inav_compass(np.random.default_rng(None if seed is None else seed + 4700))]
        super().__init__(*args, **kwargs)
        self.mav = mavlink.MAVLink(_NoMavlink(), srcSystem=self.system_id)  # the engine's MAVLink side, silenced
        mounted = self.faults.mountings()
        for index, mag in enumerate(self.magnetometers):  # mounted as INAV's DEFAULT expects, unless a fault says
            if index not in mounted or mounted[index][0] == 0:
                mag.mount(MAV_CW270FLIP, mag.misalignment_deg)
        self._parsers_msp: dict[object, MspParser] = {}
        self._alignment = np.array(INAV_ALIGNMENTS[INAV_COMPASS_DEFAULT_ALIGNMENT], float)
        self._last_imu_request = -np.inf
        self._calibration_written = False  # since the last RAW_IMU request
        self.boot_uid = self.uid
        self.refused: list[int] = []  # commands answered with an error reply (tests read it)

    # ------------------------------------------------------------------ the engine's flavour hooks
    def param_specs(self) -> list[ParamSpec]:
        return [ParamSpec(s.name, MAV_TYPES[s.type], s.default) for s in SETTINGS]

    def wire_value(self, spec: ParamSpec, value: ParamValue) -> float:
        return float(value)

    def handle_param_set(self, msg: Any) -> None:
        return None

    def load_from_storage(self, stored: dict[str, ParamValue]) -> None:
        """Boot (and ``readEEPROM`` after a save): the stored settings, DEFAULT alignment rewritten to
        CW270FLIP; the compass's alignment latched — a later write of ``align_mag`` waits for the next boot."""
        self.table.load(stored)
        if self.table.values["align_mag"] == 0:
            self.table.set("align_mag", INAV_COMPASS_DEFAULT_ALIGNMENT)

    def _boot(self, now: float, first: bool = False) -> None:
        super()._boot(now, first)
        if not first and self.faults.uid_changes_at_reboot:
            self.boot_uid = self.uid ^ 0x5A5A5A
        values = self.table.values
        external = [values[f"align_mag_{a}"] for a in ("roll", "pitch", "yaw")]
        if any(external):  # an external compass's custom angles replace align_mag (compassInit)
            self._alignment = inav_external_rotation(*external)
        else:
            self._alignment = np.array(INAV_ALIGNMENTS[int(values["align_mag"]) or INAV_COMPASS_DEFAULT_ALIGNMENT],
                                       float)
        self._next_heartbeat = float("inf")
        self._parsers_msp.clear()

    def corrected_ut(self, sensor: SimMagnetometer, raw_ut: NDArray) -> NDArray:
        """INAV's output for a raw reading (counts, body axes: radius 1024 once calibrated), not µT."""
        return self.magnetometer_out(self.raw_counts(raw_ut)).astype(float)

    def stream_message(self, msg_id: int, now: float) -> Any | None:
        return None

    # ------------------------------------------------------------------ the compass
    def raw_counts(self, reading_ut: NDArray) -> NDArray:
        """The driver's int16 counts, in INAV's sensor axes, for a reading in the engine's (µT)."""
        return np.clip(np.round(FLIP @ np.asarray(reading_ut) * self.counts_per_ut), -32768, 32767).astype(int)

    def magnetometer_out(self, raw: NDArray) -> NDArray:
        """``compassUpdate``: the calibration per axis in the sensor's axes, then the alignment, as int16."""
        values = self.table.values
        calibrated = [truncating_div((int(raw[i]) - int(values[f"magzero_{a}"])) * 1024, int(values[f"maggain_{a}"]))
                      for i, a in enumerate("xyz")]
        aligned = self._alignment @ np.array(calibrated, float)
        return np.array([int16(int(v)) for v in aligned])

    # ------------------------------------------------------------------ MSP
    def _receive(self, peer: object, data: bytes) -> None:
        parser = self._parsers_msp.setdefault(peer, MspParser())
        for frame in parser.feed(data):
            if frame.direction != REQUEST:
                continue
            try:
                answer = self._answer(frame.command, frame.payload)
            except (ValueError, KeyError, struct.error, IndexError):
                answer = None
            if answer is None:
                self.refused.append(frame.command)
            encode = encode_msp_v2 if frame.version == 2 else encode_msp_v1
            if not (self.faults.lose_reboot_ack and frame.command == Msp.REBOOT):
                self._transmit(encode(frame.command, answer or b"", REPLY if answer is not None else ERROR))
            self._act_after_answer()
        self.bad_frames = sum(p.bad_frames for p in self._parsers_msp.values())

    def _armed(self) -> bool:
        return self.faults.armed

    def _answer(self, command: int, payload: bytes) -> bytes | None:
        now = time.monotonic()
        if command == Msp.API_VERSION:
            return bytes([0, 2, 5])
        if command == Msp.FC_VARIANT:
            return (self.faults.msp_variant or "INAV").encode()[:4].ljust(4, b" ")
        if command == Msp.FC_VERSION:
            return bytes(self.firmware_version)
        if command == Msp.BOARD_INFO:
            return self.BOARD + struct.pack("<HBB", 0, 0, 0) + bytes([len(self.TARGET)]) + self.TARGET
        if command == Msp.UID:
            return struct.pack("<III", self.boot_uid & 0xFFFFFFFF, (self.boot_uid >> 32) & 0xFFFFFFFF, self.system_id)
        if command == Msp.INAV_STATUS:
            flags = INAV_ARMED_FLAG if self._armed() else 0
            values = self.table.values  # compassUpdate: all offsets 0 and all gains 1024 is "not calibrated"
            if all(values[f"magzero_{a}"] == 0 and values[f"maggain_{a}"] == 1024 for a in "xyz"):
                flags |= COMPASS_NOT_CALIBRATED
            return struct.pack("<HHHHBI", 1000, 0, 0, 5, 0, flags) + bytes(8)
        if command == Msp.INAV_MISC2:
            return struct.pack("<IIBB", int(now - self._booted_at), 0, 0, 0)
        if command == Msp.RAW_IMU:
            return self._raw_imu(now)
        if command == Msp.COMMON_SETTING:
            setting = self._setting(payload)
            if setting is None:
                return None
            return struct.pack(SETTING_FORMATS[setting.type], self.table.values[setting.name])
        if command == Msp.COMMON_SETTING_INFO:
            setting = self._setting(payload)
            return None if setting is None else encode_setting_info(self._info(setting))
        if command == Msp.COMMON_SET_SETTING:
            return self._set_setting(payload)
        if command == Msp.EEPROM_WRITE:
            if self._armed():
                return None
            self.write_storage(dict(self.table.values))
            self.load_from_storage(self.read_storage())  # readEEPROM: what is stored now, fixed as at boot
            return b""
        if command == Msp.REBOOT:
            if not self._armed():
                self.after_ack(lambda: self.request_reboot(self.REBOOT_DELAY_S))
            return b""
        return None

    def _setting(self, payload: bytes) -> InavSetting | None:
        """``mspReadSetting``: a NUL-terminated name, or 0 and a u16 index."""
        if payload[:1] == b"\0":
            index = struct.unpack_from("<H", payload, 1)[0]
            return SETTINGS[index] if index < len(SETTINGS) else None
        name = payload.split(b"\0", 1)[0].decode("ascii", "replace")
        return self.settings.get(name)

    def _info(self, setting: InavSetting) -> SettingInfo:
        mode = 0x40 if setting.names else 0
        return SettingInfo(setting.name, 1, setting.type, 0, mode, setting.minimum, setting.maximum,
                           SETTINGS.index(setting), setting.names, self.table.values[setting.name])

    def _set_setting(self, payload: bytes) -> bytes | None:
        """``mspSetSettingCommand``: the value read in the setting's own width (more bytes are ignored, so a
        wider value is stored truncated), held to the range, used at once, not saved."""
        setting = self._setting(payload)
        if setting is None:
            return None
        rest = payload[1 + 2:] if payload[:1] == b"\0" else payload[len(setting.name) + 1:]
        fmt = SETTING_FORMATS[setting.type]
        if len(rest) < struct.calcsize(fmt):
            return None
        value = struct.unpack(fmt, rest[:struct.calcsize(fmt)])[0]
        if not setting.minimum <= value <= setting.maximum:
            return None
        self.table.set(setting.name, value)
        self._calibration_written |= setting.name in CALIBRATION_SETTINGS
        return b""

    def _raw_imu(self, now: float) -> bytes:
        if now - self._last_imu_request > NEW_TUMBLE_GAP_S or self._calibration_written:
            self._motion_index += 1  # the station starts polling again: the operator starts (another) tumble
            self._mag_stream_started = now
        self._last_imu_request, self._calibration_written = now, False
        accel_g = FLIP @ self.accel_mg(now) / 1000.0  # the specific force, forward-left-up: +1 g on Z when level
        acc = [int16(round(v * 512)) for v in accel_g]
        mag = [0, 0, 0]
        if self.detected:
            sensor = self.detected[0]
            mag = [int(v) for v in self.magnetometer_out(self.raw_counts(self.held_reading_ut(sensor, now)))]
        return struct.pack("<9h", *acc, 0, 0, 0, *mag)

    def _advance(self, now: float, answering: bool = False) -> None:
        if (self.power is Power.UP and self._mag_stream_started is not None
                and now - self._last_imu_request > NEW_TUMBLE_GAP_S):
            self._mag_stream_started = None  # polling stopped: the fault's "after the stream started" restarts
        super()._advance(now, answering)
