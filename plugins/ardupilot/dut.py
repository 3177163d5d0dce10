"""The ArduPilot DUT backend: calibrate one compass through pymavlink, persist, prove it survived.

Sequence as the core's phases drive it: connect (heartbeat, version, compass ids) → prepare
(COMPASS_LEARN off, read the calibration held now) → samples (RAW_IMU / SCALED_IMU2/3 of the
chosen compass, the firmware's correction inverted) → parameters (OFS/DIA/ODI/SCALE of the set
whose DEV_ID is the sensor, checked against ArduPilot's limits) → commit (force-save the device
ids) → reboot and reconnect → read back, prearm check → restore COMPASS_LEARN.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import numpy as np

from magline.core.dut import DutError, NotRestored, ParamValue, SampleChunk, UnitInfo, await_new_boot
from magline.core.faults import StationFault
from magline.core.fit import FitResult
from magline.core.readings import RepeatFilter, untruncate_mg
from magline.core.station.schema import Product
from magline.plugins.ardupilot.calibration import (
    SETS,
    HeldCalibration,
    check_firmware_limits,
    fit_to_params,
    rename_for_set,
    set_names,
)
from magline.plugins.ardupilot.link import ML, ArduPilotLink
from magline.plugins.ardupilot.options import ArduPilotOptions

# compass priority 0 / 1 / 2 (= set 1 / 2 / 3 after the boot-time reorder) streams in these messages
STREAMS = (("RAW_IMU", ML.MAVLINK_MSG_ID_RAW_IMU), ("SCALED_IMU2", ML.MAVLINK_MSG_ID_SCALED_IMU2),
           ("SCALED_IMU3", ML.MAVLINK_MSG_ID_SCALED_IMU3))
INT_PARAMS = ("COMPASS_DEV_ID", "COMPASS_PRIO", "COMPASS_LEARN", "COMPASS_OFFS_MAX", "COMPASS_MOTCT")
CHUNK = 10
RESTORE_RECONNECT_S = 3.0  # a vehicle that does not answer by then is reported as not restored
COMPASS_PREARM = "PreArm: Compass"


def _firmware(version: int) -> str:
    return f"{version >> 24 & 0xFF}.{version >> 16 & 0xFF}.{version >> 8 & 0xFF}"


class ArduPilotDut:
    def __init__(self, product: Product, options: ArduPilotOptions) -> None:
        self.product = product
        self.opts = options
        self.link = ArduPilotLink(product.connection, param_timeout_s=options.param_timeout_s)
        self.device_id = 0
        self.suffix = ""  # set of the calibrated compass now
        self.suffix_written = ""  # set it had when the calibration was written
        self.ids: dict[str, int] = {}
        self.offs_max_mg = 1800.0
        self.held: HeldCalibration | None = None
        self._saved_learn: int | None = None

    # ------------------------------------------------------------------ link
    def connect(self) -> UnitInfo:
        heartbeat = self.link.open(self.opts.connect_timeout_s)
        if heartbeat.autopilot != ML.MAV_AUTOPILOT_ARDUPILOTMEGA:
            self.link.close()
            raise StationFault(f"the vehicle on {self.product.connection} is not ArduPilot "
                           f"(MAV_AUTOPILOT {heartbeat.autopilot}); check the product's backend")
        version = self.link.request_message(ML.MAVLINK_MSG_ID_AUTOPILOT_VERSION, "AUTOPILOT_VERSION")
        firmware = _firmware(version.flight_sw_version) if version is not None else "unknown"
        self._read_ids()
        self.device_id = self._selected_id()
        self.suffix = self.suffix_written = self._suffix_of(self.device_id)
        self.offs_max_mg = self.link.get("COMPASS_OFFS_MAX")
        return UnitInfo(autopilot="ArduPilot", firmware=firmware, sensors=[i for i in self.ids.values() if i],
                        selected_sensor=self.device_id, soft_iron_model="full",
                        extra={"compass_set": SETS.index(self.suffix) + 1,
                               "capabilities": int(version.capabilities) if version is not None else 0})

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
        names = [n for group in set_names(self.suffix).values() for n in group if "DEV_ID" not in n]
        self.held = HeldCalibration.from_params({n: self.link.get(n) for n in names}, self.suffix)

    def restore(self) -> None:
        """COMPASS_LEARN back to what it was (ArduPilot stores every PARAM_SET at once, so the change
        is in storage either way); after a closed link, one short reconnect is tried first."""
        if self._saved_learn is None:
            return
        try:
            if self.link.conn is None:
                self.link.open(min(self.opts.connect_timeout_s, RESTORE_RECONNECT_S))
            self.link.set("COMPASS_LEARN", self._saved_learn)
        except DutError as exc:
            raise NotRestored(str(exc), {"COMPASS_LEARN": f"0 (was {self._saved_learn})"}) from exc
        self._saved_learn = None

    # ------------------------------------------------------------------ data
    def samples(self, rate_hz: float) -> Iterator[SampleChunk]:
        if self.held is None:
            raise DutError("prepare() must run before acquisition")
        kind, msg_id = STREAMS[SETS.index(self.suffix)]
        self.link.drain()
        self.link.set_message_interval(msg_id, rate_hz)
        readings = RepeatFilter()
        try:
            rows: list[tuple[float, float, float]] = []
            times: list[float] = []
            while True:
                msg = self.link.recv(kind, self.opts.stream_timeout_s)
                if msg is None:
                    self.link.require_alive(f"link lost during acquisition: no {kind} for "
                                            f"{self.opts.stream_timeout_s:g} s")
                    raise DutError(f"the vehicle answers but sent no {kind} for {self.opts.stream_timeout_s:g} s: "
                                   f"compass {self.device_id} delivers no readings")
                if not readings.accept(msg.xmag, msg.ymag, msg.zmag):
                    continue  # the stream is faster than the compass: the same reading again
                rows.append((msg.xmag, msg.ymag, msg.zmag))
                times.append(msg.time_usec / 1000.0 if kind == "RAW_IMU" else float(msg.time_boot_ms))
                if len(rows) >= CHUNK:
                    corrected_mg = untruncate_mg(np.array(rows, float))
                    yield SampleChunk(mag_ut=self.held.raw_ut(corrected_mg), t_ms=np.array(times),
                                      repeats=readings.take_repeats())
                    rows, times = [], []
        finally:
            with contextlib.suppress(DutError):  # when the link is gone the stream stops with it
                self.link.set_message_interval(msg_id, 0)

    # ------------------------------------------------------------------ parameters
    def calibration_params(self, fit: FitResult) -> dict[str, ParamValue]:
        params = fit_to_params(fit, self.suffix)
        check_firmware_limits(params, self.suffix, self.offs_max_mg)
        self.suffix_written = self.suffix
        return dict(params)

    def read_params(self, names: list[str]) -> dict[str, ParamValue]:
        out: dict[str, ParamValue] = {}
        for name in names:
            value = self.link.get(rename_for_set(name, self.suffix_written, self.suffix))
            out[name] = int(value) if name.startswith(INT_PARAMS) else value
        return out

    def write_params(self, params: dict[str, ParamValue]) -> dict[str, ParamValue]:
        return {name: self.link.set(name, float(value)) for name, value in params.items()}

    def commit(self) -> None:
        """Save the device ids: without it the compass is 'not calibrated' after reboot (PR #16591)."""
        if self.opts.force_save_device_ids:
            self.link.require_accepted(ML.MAV_CMD_PREFLIGHT_CALIBRATION, "force-save of the compass device ids",
                                       0, 76)

    # ------------------------------------------------------------------ power cycle and proof
    def reboot(self) -> None:
        self.link.require_accepted(ML.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, "reboot", 1)
        self.link.close()  # ArduPilot drops the connection; a fresh one proves the new boot

    def release_link(self) -> None:
        self.link.close()

    def await_boot(self, since: float) -> dict[str, float]:
        def reconnect(remaining_s: float) -> None:
            self.link.close()
            self.link.open(remaining_s)

        reconnected, uptime = await_new_boot(reconnect, self._uptime_s, since, self.opts.boot_timeout_s)
        self._read_ids()
        if self.device_id in self.ids.values():
            self.suffix = self._suffix_of(self.device_id)
        return {"time_to_heartbeat_s": reconnected, "uptime_at_reconnect_s": uptime}

    def _uptime_s(self) -> float | None:
        msg = self.link.request_message(ML.MAVLINK_MSG_ID_SYSTEM_TIME, "SYSTEM_TIME")
        return None if msg is None else msg.time_boot_ms / 1000.0

    def selected_sensor_present(self) -> bool:
        return self.device_id in self.ids.values()

    def calibrated_field_ut(self, count: int) -> np.ndarray:
        """The set's own stream after the power cycle: the field the firmware corrects with the
        calibration as it holds it now (distinct readings, truncation undone)."""
        kind, msg_id = STREAMS[SETS.index(self.suffix)]
        self.link.drain()
        self.link.set_message_interval(msg_id, 50.0)
        readings = RepeatFilter()
        rows: list[tuple[float, float, float]] = []
        try:
            while len(rows) < count:
                msg = self.link.recv(kind, self.opts.stream_timeout_s)
                if msg is None:
                    self.link.require_alive(f"waiting for {kind} after the power cycle")
                    raise DutError(f"the vehicle answers but sent no {kind} after the power cycle")
                if readings.accept(msg.xmag, msg.ymag, msg.zmag):
                    rows.append((msg.xmag, msg.ymag, msg.zmag))
        finally:
            with contextlib.suppress(DutError):
                self.link.set_message_interval(msg_id, 0)
        return untruncate_mg(np.array(rows, float)) / 10.0

    def persistence_problems(self) -> list[str]:
        """Run ArduPilot's arming checks: a compass whose DEV_ID was not saved is 'not calibrated'.

        Every compass PreArm text fails the unit: ArduPilot's text does not say which compass, and
        a compass in use that is left uncalibrated blocks arming anyway (disable it with
        COMPASS_USEn = 0 or calibrate it too)."""
        self.link.statustexts.clear()
        self.link.require_accepted(ML.MAV_CMD_RUN_PREARM_CHECKS, "prearm check")
        self.link.recv("NO_SUCH_MESSAGE", self.opts.prearm_wait_s)  # collect STATUSTEXT meanwhile
        return sorted({t for t in self.link.statustexts if t.startswith(COMPASS_PREARM)})
