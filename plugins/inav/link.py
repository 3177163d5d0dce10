"""INAV over MSP: who answers, its settings by name in their own types, its arming state, its uptime and
its compass and accelerometer readings.  What the backend needs of the link, and nothing of the run."""

from __future__ import annotations

import contextlib
import struct
import time
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from magline.plugin import (
    INAV_ARMED_FLAG,
    INAV_TO_FRD,
    DutError,
    LinkError,
    Msp,
    MspClient,
    MspRefused,
    Refusals,
    SettingInfo,
    StationFault,
    parse_setting_info,
)

GRAVITY_MSS = 9.80665
ACC_PER_G = 512.0  # MSP_RAW_IMU's accelerometer: g · 512


class NotInav(DutError, StationFault):
    """Another firmware answers MSP (Betaflight: "BTFL"): the station cannot judge this unit as INAV."""


class Armed(DutError, StationFault):
    """The unit is armed: INAV refuses to save and ignores a reboot, so nothing is written."""


@dataclass(frozen=True)
class Identity:
    variant: str
    version: str
    api: str
    board: str
    uid: str  # the MCU's unique id, hex: the unit's identity across boots


@dataclass(frozen=True)
class ImuReading:
    """One ``MSP_RAW_IMU``: INAV's accelerometer (m/s², specific force, in magline's body axes
    forward-right-down) and its compass output (counts, calibrated and aligned as the firmware holds it now,
    in INAV's own body axes forward-left-up)."""

    accel_mss: NDArray
    mag_counts: NDArray


class InavLink:
    def __init__(self, address: str, reply_timeout_s: float, reply_resends: int = 2) -> None:
        self.address = address
        self.reply_timeout_s = reply_timeout_s
        self.reply_resends = reply_resends
        self.client: MspClient | None = None
        self.infos: dict[str, SettingInfo] = {}

    def open(self, timeout_s: float, nothing_listens_s: float | None = None) -> None:
        """Connect, retrying until ``timeout_s``: a board still booting refuses the connection.
        ``nothing_listens_s``: connections refused that long end it at once (a first connection)."""
        deadline = time.monotonic() + timeout_s
        refusals = Refusals(nothing_listens_s)
        while True:
            try:
                self.client = MspClient.connect(self.address, self.reply_timeout_s, connect_timeout_s=max(
                    min(deadline - time.monotonic(), 2.0), 0.1), resends=self.reply_resends)
                self.request(Msp.API_VERSION)  # answering, not just accepting the connection
                return
            except LinkError as exc:
                self.close()
                if refusals.over(exc):
                    raise LinkError(refusals.words(self.address)) from None
                if time.monotonic() >= deadline:
                    raise LinkError(f"no INAV answers MSP on {self.address} within {timeout_s:g} s ({exc})") from None
                time.sleep(0.1)

    def close(self) -> None:
        if self.client is not None:
            self.client.close()
            self.client = None

    def request(self, command: int, payload: bytes = b"", resends: int | None = None) -> bytes:
        if self.client is None:
            raise LinkError(f"the MSP link to {self.address} is closed")
        return self.client.request(command, payload, resends=resends)

    # ------------------------------------------------------------------ identity and state
    def identify(self) -> Identity:
        variant = self.request(Msp.FC_VARIANT)[:4].decode("ascii", "replace").strip()
        if variant != "INAV":
            raise NotInav(f"the unit on {self.address} answers MSP as {variant!r}"
                          f"{' (Betaflight)' if variant == 'BTFL' else ''}, not INAV: this station's product runs INAV")
        api = self.request(Msp.API_VERSION)
        version = self.request(Msp.FC_VERSION)
        board = self.request(Msp.BOARD_INFO)
        target = board[9:9 + board[8]].decode("ascii", "replace") if len(board) > 8 else ""
        uid = self.request(Msp.UID)
        return Identity(variant, ".".join(map(str, version[:3])), f"{api[1]}.{api[2]}" if len(api) >= 3 else "?",
                        (board[:4].decode("ascii", "replace") + (f" ({target})" if target else "")).strip(), uid.hex())

    def arming_flags(self) -> int:
        """INAV's ``armingFlags`` (``MSP2_INAV_STATUS``, u32 at byte 9): armed, and why arming is disabled."""
        payload = self.request(Msp.INAV_STATUS)
        if len(payload) < 13:
            raise LinkError(f"MSP2_INAV_STATUS answered {len(payload)} bytes: no arming flags in it")
        return int(struct.unpack_from("<I", payload, 9)[0])

    def armed(self) -> bool:
        return bool(self.arming_flags() & INAV_ARMED_FLAG)

    def require_disarmed(self, doing: str) -> None:
        if self.armed():
            raise Armed(f"the unit is armed: INAV refuses to save or reboot while armed — disarm it "
                        f"({doing} was not done)")

    def uptime_s(self) -> float | None:
        try:
            return float(struct.unpack_from("<I", self.request(Msp.INAV_MISC2))[0])
        except (MspRefused, struct.error):
            return None  # a release without MSP2_INAV_MISC2 does not say

    # ------------------------------------------------------------------ settings
    def info(self, name: str) -> SettingInfo:
        if name not in self.infos:
            try:
                payload = self.request(Msp.COMMON_SETTING_INFO, name.encode() + b"\0")
            except MspRefused:
                raise DutError(f"this INAV has no setting {name}") from None
            try:
                self.infos[name] = parse_setting_info(name, payload)
            except ValueError as exc:
                raise DutError(f"INAV's description of {name} is not understood: {exc}") from None
        return self.infos[name]

    def read(self, name: str) -> int | float:
        info = self.info(name)
        try:
            return info.decode(self.request(Msp.COMMON_SETTING, name.encode() + b"\0"))
        except (MspRefused, struct.error):
            raise DutError(f"INAV did not answer the value of {name}") from None

    def check(self, name: str, value: int | float) -> None:
        """A value the setting cannot hold is refused here, before anything is written."""
        info = self.info(name)
        if info.type != 5 and (not isinstance(value, int) or isinstance(value, bool)):
            raise DutError(f"{name} is an integer setting in INAV, not {value!r}")
        if not info.minimum <= value <= info.maximum:
            raise DutError(f"{name} = {value} is outside INAV's range [{info.minimum}, {info.maximum}]: not written")

    def write(self, name: str, value: int | float) -> None:
        info = self.info(name)
        try:
            self.request(Msp.COMMON_SET_SETTING, name.encode() + b"\0" + info.encode(value))
        except MspRefused:
            raise DutError(f"INAV refused {name} = {value}") from None

    def save(self) -> None:
        try:
            self.request(Msp.EEPROM_WRITE)
        except MspRefused:
            raise DutError("INAV refused to save its settings (MSP_EEPROM_WRITE): armed since the check?") from None

    def reboot(self) -> None:
        """``MSP_REBOOT``, sent once: INAV answers, then reboots.  A reply that never comes, or a link that drops
        before it, proves nothing either way (lost on the way, or the board already going down): the new boot's
        uptime will.  A request sent again could reach the new boot and reboot it once more."""
        with contextlib.suppress(LinkError):  # MspTimeout among them
            self.request(Msp.REBOOT, resends=0)

    # ------------------------------------------------------------------ readings
    def imu(self) -> ImuReading:
        values = struct.unpack("<9h", self.request(Msp.RAW_IMU)[:18])
        # INAV's accelerometer is the specific force in its body axes, forward-left-up (+1 g on Z at rest):
        # the same force in magline's forward-right-down axes has y and z the other way
        accel = np.array(INAV_TO_FRD, float) @ np.array(values[0:3], float) / ACC_PER_G * GRAVITY_MSS
        return ImuReading(accel, np.array(values[6:9], float))
