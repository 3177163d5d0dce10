"""MSP, the MultiWii Serial Protocol INAV speaks: v1 and v2 framing with their checksums, and a small
request/response client over TCP or a serial port.  Here, beside SCPI and MAVLink's helpers, because both
sides use it: the INAV backend (issue 47, through :mod:`magline.plugin`) and the INAV simulator.

Why written here: no maintained Python MSP library exists (yamspy's last release is from 2021,
msp-python3's from 2020), and the protocol is small.  Frames (INAV's ``msp_serial.c``):

* v1: ``$M<`` (request) / ``$M>`` (reply) / ``$M!`` (error reply), size (u8), command (u8), payload,
  checksum = XOR of size, command and payload;
* v2: ``$X<`` / ``$X>`` / ``$X!``, flag (u8), function (u16 LE), size (u16 LE), payload, checksum =
  CRC-8/DVB-S2 (polynomial 0xD5) of everything from the flag to the payload's end.

An error reply (``!``) is the firmware saying no to that command — :class:`MspRefused`, with its
number; a reply that never comes is :class:`MspTimeout`; a frame whose checksum is wrong is dropped and
counted, as the firmware does with the station's.
"""

from __future__ import annotations

import socket
import struct
import time
from collections.abc import Iterator
from dataclasses import dataclass
from enum import IntEnum

from magline.core.dut import DutError, LinkError
from magline.core.links.serial_port import SerialAddress

V1_MAX_PAYLOAD = 254  # 255 announces a jumbo frame, which no command here needs
V1_MAX_COMMAND = 255  # a v1 command is one byte; INAV's settings (0x1003 …) are v2 functions
REQUEST, REPLY, ERROR = b"<", b">", b"!"


class Msp(IntEnum):
    """The commands a calibration needs, numbered as INAV's ``msp_protocol.h`` and
    ``msp_protocol_v2_common.h`` / ``msp_protocol_v2_inav.h`` number them (``docs/firmware.md``, *INAV*)."""

    API_VERSION = 1  # protocol version, API major, API minor (u8 each)
    FC_VARIANT = 2  # four letters: "INAV" (Betaflight: "BTFL")
    FC_VERSION = 3  # major, minor, patch (u8 each)
    BOARD_INFO = 4  # board identifier (4 letters), hardware revision (u16), …, target name
    REBOOT = 68  # ignored while armed (ACKed, nothing happens)
    RAW_IMU = 102  # 9 × int16: accelerometer (g · 512), gyro (°/s), magnetometer (calibrated, aligned)
    UID = 160  # 3 × u32: the MCU's unique id
    EEPROM_WRITE = 250  # save every setting; an error reply while armed
    COMMON_SETTING = 0x1003  # a setting's value by name (NUL-terminated) or by 0 + u16 index
    COMMON_SET_SETTING = 0x1004  # name, NUL, the value in the setting's own type
    COMMON_SETTING_INFO = 0x1007  # type, range, index … of a setting (:func:`parse_setting_info`)
    INAV_STATUS = 0x2000  # …, arming flags (u32 at byte 9)
    INAV_MISC2 = 0x203A  # uptime (u32 s), flight time (u32 s), throttle, auto throttle


# INAV's setting types (``fc/settings.h``: the low bits of a setting's packed type) and their wire format
SETTING_FORMATS = {0: "<B", 1: "<b", 2: "<H", 3: "<h", 4: "<I", 5: "<f"}
SETTING_TYPE_NAMES = {0: "uint8", 1: "int8", 2: "uint16", 3: "int16", 4: "uint32", 5: "float"}
MODE_LOOKUP = 0x40  # a setting whose values are names (``align_mag``: DEFAULT, CW0, …)
INAV_ARMED_FLAG = 1 << 2  # INAV's arming flag ``ARMED`` (``fc/runtime_config.h``)


# INAV's sensor alignments, ``align_mag``'s values in its ``alignment`` table, each as the rotation
# ``applySensorAlignment`` applies (``v_body = R·v_sensor``, rows).  DEFAULT (0) means CW270FLIP for the
# compass (``compassInit``; ``validateAndFixConfig`` also rewrites the stored 0 to 8).  The compass takes
# its alignment at boot only: a written ``align_mag`` is used from the next boot.
INAV_ALIGNMENT_NAMES = ("DEFAULT", "CW0", "CW90", "CW180", "CW270", "CW0FLIP", "CW90FLIP", "CW180FLIP", "CW270FLIP")
INAV_ALIGNMENTS: dict[int, tuple[tuple[int, int, int], ...]] = {
    1: ((1, 0, 0), (0, 1, 0), (0, 0, 1)),
    2: ((0, 1, 0), (-1, 0, 0), (0, 0, 1)),
    3: ((-1, 0, 0), (0, -1, 0), (0, 0, 1)),
    4: ((0, -1, 0), (1, 0, 0), (0, 0, 1)),
    5: ((-1, 0, 0), (0, 1, 0), (0, 0, -1)),
    6: ((0, 1, 0), (1, 0, 0), (0, 0, -1)),
    7: ((1, 0, 0), (0, -1, 0), (0, 0, -1)),
    8: ((0, -1, 0), (-1, 0, 0), (0, 0, -1)),
}
INAV_COMPASS_DEFAULT_ALIGNMENT = 8  # what DEFAULT means for the compass

# INAV's axes against magline's (``v_frd = INAV_TO_FRD · v_inav``).  INAV's body is forward-left-up:
# its attitude turns the body into north-west-up (``flight/imu.c``: ``imuTransformVectorBodyToEarth``
# rotates, then flips y to reach north-east-up), its accelerometer reads +1 g on Z at rest (the specific
# force, up: SITL's fake accelerometer takes X-Plane's normal load, +1 level), and its compass reaches
# ``MSP_RAW_IMU`` in the same axes.  Its sensor alignments turn sensor axes of the same kind.  magline's body
# is forward-right-down, as PX4's and ArduPilot's: one flips y and z, a rotation ``R`` of INAV's is
# ``F·R·F`` in magline's (:func:`inav_rotation_in_frd`: CWn is Yaw n).
INAV_TO_FRD: tuple[tuple[int, int, int], ...] = ((1, 0, 0), (0, -1, 0), (0, 0, -1))


def inav_rotation_in_frd(rotation):
    """A rotation between INAV's axes (forward-left-up kind) as the same turn between magline's
    (forward-right-down kind): ``F·R·F`` with ``F`` = :data:`INAV_TO_FRD` (its own inverse, so the same
    call turns one of magline's back into INAV's)."""
    import numpy as np

    flip = np.array(INAV_TO_FRD, float)
    return flip @ np.asarray(rotation, float) @ flip


def inav_external_rotation(roll_dd: float, pitch_dd: float, yaw_dd: float):
    """``v_body = R·v_sensor`` for an external compass's ``align_mag_roll/pitch/yaw`` (0.1°): INAV's
    ``rotationMatrixFromAngles`` builds ``M = Rx(roll)·Ry(pitch)·Rz(yaw)`` (Tait–Bryan X1 Y2 Z3,
    ``common/maths.c``) and ``rotationMatrixRotateVector`` applies its transpose, so ``R = Mᵀ``.  Any
    non-zero angle replaces ``align_mag`` (and the board alignment) for the compass (``compassInit``)."""
    from scipy.spatial.transform import Rotation  # on use: scipy costs every command start

    m = Rotation.from_euler("XYZ", [roll_dd / 10.0, pitch_dd / 10.0, yaw_dd / 10.0], degrees=True).as_matrix()
    return m.T


def inav_external_angles(rotation) -> tuple[int, int, int]:
    """The ``align_mag_roll/pitch/yaw`` (0.1°, in INAV's ranges) whose :func:`inav_external_rotation` is
    ``rotation`` (``v_body = R·v_sensor``), to the 0.1° INAV holds."""
    import numpy as np
    from scipy.spatial.transform import Rotation

    roll, pitch, yaw = Rotation.from_matrix(np.asarray(rotation, float).T).as_euler("XYZ", degrees=True)
    return tuple(round(float(a) * 10.0) for a in (roll, pitch, yaw))  # type: ignore[return-value]


@dataclass(frozen=True)
class SettingInfo:
    """What ``MSP2_COMMON_SETTING_INFO`` says of a setting (INAV's ``mspSettingInfoCommand``): its name, the
    parameter group, the type (a key of :data:`SETTING_FORMATS`), section and mode bytes, the range,
    the setting's index, for a lookup setting its value names, and its value."""

    name: str
    group: int
    type: int
    section: int
    mode: int
    minimum: int
    maximum: int
    index: int
    names: tuple[str, ...]
    value: int | float

    @property
    def format(self) -> str:
        return SETTING_FORMATS[self.type]

    def encode(self, value: int | float) -> bytes:
        """``value`` in this setting's own width — what ``MSP2_COMMON_SET_SETTING`` must carry: INAV reads
        as many bytes as its type has and ignores the rest (a 4-byte 40000 for an int16 is stored as −25536)."""
        return struct.pack(self.format, value)

    def decode(self, payload: bytes) -> int | float:
        return struct.unpack(self.format, payload[:struct.calcsize(self.format)])[0]


def encode_setting_info(info: SettingInfo) -> bytes:
    """The reply's layout, field by field as ``mspSettingInfoCommand`` writes it (the simulator's side): the
    name and a NUL first (as INAV 9.1 writes it), then the fixed part."""
    out = info.name.encode() + b"\0" + struct.pack("<HBBBiIH", info.group, info.type, info.section, info.mode,
                                                   info.minimum, info.maximum & 0xFFFFFFFF, info.index)
    out += bytes([0, 0])  # profile, profile count (master)
    if info.mode == MODE_LOOKUP:
        out += b"".join(n.encode() + b"\0" for n in info.names)
    return out + struct.pack(SETTING_FORMATS[info.type], info.value)


def parse_setting_info(name: str, payload: bytes) -> SettingInfo:
    """The station's side of :func:`encode_setting_info`; a reply too short for its own layout, or one that
    describes another setting, is a :class:`ValueError` naming the setting."""
    end = payload.find(b"\0")
    described = payload[:end].decode("ascii", "replace") if end >= 0 else ""
    if end < 0 or described != name:
        raise ValueError(f"the description asked for {name} names {described or 'no setting'}")
    payload = payload[end + 1:]
    head = struct.calcsize("<HBBBiIH") + 2
    if len(payload) < head:
        raise ValueError(f"the description of setting {name} is {len(payload)} bytes, shorter than its layout")
    group, kind, section, mode, low, high, index = struct.unpack_from("<HBBBiIH", payload)
    if kind not in SETTING_FORMATS:
        raise ValueError(f"setting {name} has type {kind}, which is no number (a string setting?)")
    rest, names = payload[head:], []
    if mode == MODE_LOOKUP:
        for _ in range(high - low + 1):
            end = rest.find(b"\0")
            if end < 0:
                raise ValueError(f"the value names of setting {name} are cut short")
            names.append(rest[:end].decode("ascii", "replace"))
            rest = rest[end + 1:]
    size = struct.calcsize(SETTING_FORMATS[kind])
    if len(rest) < size:
        raise ValueError(f"the description of setting {name} lacks its value")
    value = struct.unpack(SETTING_FORMATS[kind], rest[:size])[0]
    return SettingInfo(name, group, kind, section, mode, low, high, index, tuple(names), value)


class MspRefused(DutError):
    """The firmware answered a command with an error reply."""

    def __init__(self, command: int) -> None:
        super().__init__(f"the firmware refused MSP command {command}")
        self.command = command


class MspTimeout(LinkError):
    """No reply in time: the link, not the unit (the station could not judge it)."""


def crc8_dvb_s2(data: bytes, crc: int = 0) -> int:
    """CRC-8/DVB-S2 (polynomial 0xD5, initial 0, no reflection), as MSP v2 checks its frames."""
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0xD5) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc


def encode_msp_v1(command: int, payload: bytes = b"", direction: bytes = REQUEST) -> bytes:
    if not 0 <= command <= 255:
        raise ValueError(f"MSP v1 carries commands 0–255, not {command}: use v2")
    if len(payload) > V1_MAX_PAYLOAD:
        raise ValueError(f"MSP v1 carries at most {V1_MAX_PAYLOAD} payload bytes, not {len(payload)}")
    checksum = len(payload) ^ command
    for byte in payload:
        checksum ^= byte
    return b"$M" + direction + bytes([len(payload), command]) + payload + bytes([checksum])


def encode_msp_v2(function: int, payload: bytes = b"", direction: bytes = REQUEST, flag: int = 0) -> bytes:
    if not 0 <= function <= 0xFFFF:
        raise ValueError(f"MSP v2 functions are 16-bit, not {function}")
    body = bytes([flag]) + function.to_bytes(2, "little") + len(payload).to_bytes(2, "little") + payload
    return b"$X" + direction + body + bytes([crc8_dvb_s2(body)])


@dataclass(frozen=True)
class MspFrame:
    version: int  # 1 or 2
    direction: bytes  # REQUEST, REPLY or ERROR
    command: int
    payload: bytes


class MspParser:
    """Bytes in, frames out: any split across reads, noise between frames skipped, a frame with a wrong
    checksum dropped (``bad_frames`` counts them)."""

    def __init__(self) -> None:
        self.buffer = bytearray()
        self.bad_frames = 0

    def feed(self, data: bytes) -> Iterator[MspFrame]:
        self.buffer += data
        while True:
            start = self.buffer.find(b"$")
            if start < 0:
                self.buffer.clear()
                return
            del self.buffer[:start]
            if len(self.buffer) < 3:
                return
            kind, direction = self.buffer[1:2], bytes(self.buffer[2:3])
            if kind not in (b"M", b"X") or direction not in (REQUEST, REPLY, ERROR):
                del self.buffer[:1]  # a "$" that starts no frame
                continue
            frame, used = (self._v1 if kind == b"M" else self._v2)(direction)
            if used == 0:
                return  # incomplete: wait for more
            del self.buffer[:used]
            if frame is not None:
                yield frame

    def _v1(self, direction: bytes) -> tuple[MspFrame | None, int]:
        if len(self.buffer) < 5:
            return None, 0
        size, command = self.buffer[3], self.buffer[4]
        end = 5 + size
        if len(self.buffer) < end + 1:
            return None, 0
        payload = bytes(self.buffer[5:end])
        checksum = size ^ command
        for byte in payload:
            checksum ^= byte
        if checksum != self.buffer[end]:
            self.bad_frames += 1
            return None, end + 1
        return MspFrame(1, direction, command, payload), end + 1

    def _v2(self, direction: bytes) -> tuple[MspFrame | None, int]:
        if len(self.buffer) < 8:
            return None, 0
        function = int.from_bytes(self.buffer[4:6], "little")
        size = int.from_bytes(self.buffer[6:8], "little")
        end = 8 + size
        if len(self.buffer) < end + 1:
            return None, 0
        if crc8_dvb_s2(bytes(self.buffer[3:end])) != self.buffer[end]:
            self.bad_frames += 1
            return None, end + 1
        return MspFrame(2, direction, function, bytes(self.buffer[8:end])), end + 1


class MspClient:
    """Request / reply over one byte stream (``tcp:HOST:PORT`` or ``serial:DEV[:BAUD]``).  Commands above
    255 go as v2 (INAV's settings live there); the rest as v1 unless ``v2`` is asked for.

    A request unanswered within ``timeout_s`` is sent again, ``resends`` times, before the link is called lost,
    as INAV's configurator does: one frame spoilt on a serial line, or a board that answered late (a flash
    write, a busy host), is not a lost unit.  MSP numbers no request, so a reply can only be told from a
    later one to the same command by count: a resent request leaves a reply owed, and the next request of that
    command first waits it out (at most ``timeout_s`` after the last send), so that no answer is ever taken
    for a later question (a setting read back as another's value)."""

    def __init__(self, transport, timeout_s: float = 1.0, resends: int = 2) -> None:
        self.transport = transport
        self.timeout_s = timeout_s
        self.resends = resends
        self.parser = MspParser()
        self.resent = 0  # requests sent again because no reply came in time
        self._owed: dict[int, tuple[int, float]] = {}  # command → (replies still to come, until when)

    @classmethod
    def tcp(cls, host: str, port: int, timeout_s: float = 1.0, connect_timeout_s: float = 5.0,
            resends: int = 2) -> MspClient:
        try:
            sock = socket.create_connection((host, port), timeout=connect_timeout_s)
        except OSError as exc:
            raise LinkError(f"nothing answers MSP on tcp:{host}:{port} ({exc})") from exc
        return cls(_SocketStream(sock), timeout_s, resends)

    @classmethod
    def connect(cls, address: str, timeout_s: float = 1.0, connect_timeout_s: float = 5.0,
                resends: int = 2) -> MspClient:
        """``tcp:HOST:PORT`` or ``serial:DEV[:BAUD]`` (115200 when not said; a USB CDC port ignores it)."""
        if address.startswith("tcp:"):
            host, _, port = address.removeprefix("tcp:").rpartition(":")
            if not host or not port.isdigit():
                raise ValueError(f"{address!r} is not tcp:HOST:PORT")
            return cls.tcp(host, int(port), timeout_s, connect_timeout_s, resends)
        if address.startswith("serial:"):
            where = SerialAddress.parse(address)  # SerialAddressError (a ValueError) names what is wrong
            return cls(_SerialStream(where.path, where.baud), timeout_s, resends)
        raise ValueError(f"{address!r}: an MSP connection is tcp:HOST:PORT or serial:DEV[:BAUD]")

    def request(self, command: int, payload: bytes = b"", v2: bool | None = None,
                timeout_s: float | None = None, resends: int | None = None) -> bytes:
        """The reply's payload to ``command``; :class:`MspRefused` on an error reply, :class:`MspTimeout`
        when none comes to the request nor to any of its ``resends`` (``0`` for a request that must go once:
        a reboot)."""
        use_v2 = command > V1_MAX_COMMAND if v2 is None else v2
        frame = encode_msp_v2(command, payload) if use_v2 else encode_msp_v1(command, payload)
        wait_s = self.timeout_s if timeout_s is None else timeout_s
        sends = 1 + (self.resends if resends is None else resends)
        self._settle(command)
        for sent in range(1, sends + 1):
            self.transport.write(frame)
            if sent > 1:
                self.resent += 1
            deadline = time.monotonic() + wait_s
            reply = self._next(command, deadline)
            if reply is not None:
                if sent > 1:  # the earlier sends may still be answered: those replies are not this one's
                    self._owed[command] = (sent - 1, deadline)
                if reply.direction == ERROR:
                    raise MspRefused(command)
                return reply.payload
        self._owed[command] = (sends, deadline)
        raise MspTimeout(f"no reply to MSP command {command} within {wait_s:g} s"
                         + (f", sent {sends} times" if sends > 1 else ""))

    def _settle(self, command: int) -> None:
        """Replies still owed to earlier sends of ``command`` are read and dropped, or given up at their time."""
        owed, until = self._owed.pop(command, (0, 0.0))
        while owed > 0 and self._next(command, until) is not None:
            owed -= 1

    def _next(self, command: int, deadline: float) -> MspFrame | None:
        """The next reply (or error reply) to ``command`` that arrives before ``deadline``.  Any other frame is
        dropped: a late reply to an earlier request (counted off what that command is owed), or the station's
        own echo on a shared line."""
        data = b""  # first what an earlier read brought beyond its own reply
        while True:
            for frame in self.parser.feed(data):
                if frame.direction == REQUEST:
                    continue
                if frame.command == command:
                    return frame
                owed, until = self._owed.get(frame.command, (0, 0.0))
                if owed > 1:
                    self._owed[frame.command] = (owed - 1, until)
                elif owed == 1:
                    del self._owed[frame.command]
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            data = self.transport.read(left)

    def close(self) -> None:
        self.transport.close()


class _SocketStream:
    """A TCP socket as the client's byte stream: ``read`` returns what arrived within the time given."""

    def __init__(self, sock: socket.socket) -> None:
        self.sock = sock

    def write(self, data: bytes) -> None:
        try:
            self.sock.sendall(data)
        except OSError as exc:
            raise LinkError(f"MSP link lost ({exc})") from exc

    def read(self, timeout_s: float) -> bytes:
        self.sock.settimeout(max(timeout_s, 0.001))
        try:
            data = self.sock.recv(4096)
        except TimeoutError:
            return b""
        except OSError as exc:
            raise LinkError(f"MSP link lost ({exc})") from exc
        if not data:
            raise LinkError("MSP link closed by the flight controller")
        return data

    def close(self) -> None:
        self.sock.close()


class _SerialStream:
    """A serial port (pyserial) as the client's byte stream."""

    def __init__(self, device: str, baud: int) -> None:
        import serial  # on use: a TCP link needs no serial stack

        try:
            self.port = serial.Serial(device, baud, timeout=0)
        except (OSError, serial.SerialException) as exc:
            raise LinkError(f"cannot open {device} for MSP ({exc})") from exc

    def write(self, data: bytes) -> None:
        try:
            self.port.write(data)
        except OSError as exc:
            raise LinkError(f"MSP link lost ({exc})") from exc

    def read(self, timeout_s: float) -> bytes:
        self.port.timeout = max(timeout_s, 0.001)
        try:
            return self.port.read(max(self.port.in_waiting, 1))
        except OSError as exc:
            raise LinkError(f"MSP link lost ({exc})") from exc

    def close(self) -> None:
        self.port.close()
