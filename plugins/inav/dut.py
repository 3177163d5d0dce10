"""The INAV backend: a unit over MSP, calibrated through its settings (see the package docstring)."""

from __future__ import annotations

import time
from collections.abc import Iterator
from typing import TYPE_CHECKING

import numpy as np

from magline.plugin import (
    NOTHING_LISTENS_S,
    DutError,
    ImuSeries,
    LinkError,
    Magnetometer,
    NotRestored,
    ParamValue,
    ReadingsAtRest,
    RepeatFilter,
    SampleChunk,
    UnitInfo,
    await_new_boot,
    inav_external_angles,
    inav_external_rotation,
    inav_rotation_in_frd,
    orientation_matrix,
)
from magline.plugins.inav.calibration import (
    FLIP,
    GAINS,
    NEUTRAL,
    OFFSETS,
    alignment_for,
    alignment_matrix,
    alignment_name,
    fit_to_settings,
    mav_orientation,
    output_to_ut,
)
from magline.plugins.inav.link import Identity, InavLink

if TYPE_CHECKING:
    from magline.plugin import FitResult, Product
    from magline.plugins.inav.options import InavOptions

COMPASS = 1  # INAV uses one compass and gives it no device id: magline calls it 1
EXTERNAL_ANGLES = ("align_mag_roll", "align_mag_pitch", "align_mag_yaw")
CHUNK_S = 0.1  # readings are handed on every tenth of a second


# An answer later than the link's least round trip by more than this cannot be placed in time closely
# enough to pair its compass with its accelerometer on a turning unit: it is left out (the next answer
# carries the same compass reading, which INAV holds between its compass task's updates).
LATE_ANSWER_S = 0.010


def placed_in_time(asked: float, answered: float, least_rtt_s: float) -> float | None:
    """When the board read the accelerometer and compass it answered a request with, on the station's
    clock — the middle of the request's round trip — or None when the answer was late.

    Why: INAV answers ``MSP_RAW_IMU`` as its serial task handles the request, and the readings were taken
    somewhere between the request's arrival and the answer's departure; a round trip longer than the
    link's least was lengthened on the station's side (its running fit holding the interpreter, a loaded
    PC) or the board's, and which is unknown.  The middle is then off by up to half of the lengthening: a
    tumble turning 300°/s turned tens of degrees in it, the accelerometer's track was bent there, and
    the mounting check could no longer tell the compass's time skew from a turned sensor (a good unit
    ERRORed on a loaded machine).  So an answer lengthened by more than :data:`LATE_ANSWER_S` is not
    used at all."""
    if answered - asked - least_rtt_s > LATE_ANSWER_S:
        return None
    return (asked + answered) / 2.0


COMPASS_NOT_CALIBRATED = 1 << 12  # INAV's ARMING_DISABLED_COMPASS_NOT_CALIBRATED


class InavDut:
    def __init__(self, product: Product, options: InavOptions) -> None:
        self.product = product
        self.opts = options
        self.link = InavLink(product.connection, options.reply_timeout_s, options.reply_resends)
        self.counts_per_ut = options.counts_per_gauss / 100.0
        self.boot_timeout_s = options.boot_timeout_s
        self.identity: Identity | None = None
        self.alignment = 0
        self.angles: tuple[int, ...] = (0, 0, 0)  # align_mag_roll/pitch/yaw (0.1°): any non-zero: external
        self.external = False
        self.has_external = False
        self.to_body = alignment_matrix(0)
        self._previous: dict[str, ParamValue] | None = None  # the calibration prepare() made neutral
        self._wrote_calibration = False  # write_params() since the last save wrote offsets or gains
        self._calibration_saved = False  # a calibration of the station's own is saved: nothing to restore
        self._field_ut: float | None = None  # the field the written gains map to 1024 counts
        self.present = True

    # ------------------------------------------------------------------ link
    def connect(self) -> UnitInfo:
        self.link.open(self.opts.connect_timeout_s, NOTHING_LISTENS_S)
        self.identity = self.link.identify()
        for name in (*OFFSETS, *GAINS, "align_mag"):
            self.link.info(name)  # a firmware without one cannot hold the calibration: DutError names it
        self.has_external = all(self._has(n) for n in EXTERNAL_ANGLES)
        self._read_alignment()
        identity = self.identity
        return UnitInfo(autopilot="INAV", firmware=identity.version, sensors=[COMPASS], selected_sensor=COMPASS,
                        soft_iron_model="diagonal",
                        extra={"uid": identity.uid, "board": identity.board, "msp_api": identity.api,
                               "align_mag": alignment_name(self.alignment),
                               "counts_per_gauss": self.opts.counts_per_gauss,
                               "soft_iron_model_why": "INAV holds per-axis gains (maggain_x/y/z) only"},
                        magnetometers=[self._magnetometer()])

    def _has(self, name: str) -> bool:
        try:
            self.link.info(name)
        except DutError:
            return False
        return True

    def _read_alignment(self) -> None:
        """The alignment the compass uses, as it booted: ``align_mag_roll/pitch/yaw`` when any is set (an
        external compass), else ``align_mag`` (DEFAULT means CW270FLIP)."""
        self.alignment = int(self.link.read("align_mag"))
        self.angles = tuple(int(self.link.read(n)) for n in EXTERNAL_ANGLES) if self.has_external else (0, 0, 0)
        self.external = any(self.angles)
        self.to_body = (inav_rotation_in_frd(inav_external_rotation(*self.angles)) if self.external
                        else alignment_matrix(self.alignment))

    def _magnetometer(self) -> Magnetometer:
        """The readings are turned back into the sensor's axes here; INAV turns them into the body by
        ``align_mag``, the setting a mounting fix is written to."""
        return Magnetometer(device_id=COMPASS, label="compass", external=self.external or None,
                            orientation=mav_orientation(self.to_body), readings_rotated=False,
                            fix_params=list(EXTERNAL_ANGLES) if self.external else ["align_mag"],
                            range_ut=32767 / self.counts_per_ut,
                            rotation=self.to_body.tolist() if self.external else None)

    def use_magnetometers(self, device_ids: list[int]) -> None:
        if list(device_ids) != [COMPASS]:
            raise DutError(f"INAV uses one compass (magline's id {COMPASS}), not {device_ids}")

    def close(self) -> None:
        self.link.close()

    # ------------------------------------------------------------------ neutral calibration
    def prepare(self) -> None:
        """INAV streams its compass calibrated: the station writes a neutral calibration (offsets 0, gains
        1024) and saves it, so the readings are the sensor's own counts; the unit's previous values are kept
        for :meth:`restore`."""
        self.link.require_disarmed("the neutral calibration before the tumble")
        if self._previous is None:
            self._previous = {name: self.link.read(name) for name in NEUTRAL}
        self._calibration_saved = False
        for name, value in NEUTRAL.items():
            self.link.write(name, value)
        self.link.save()

    def restore(self) -> None:
        """Put the unit's previous calibration back (RAM and storage) unless the station's own was saved."""
        if self._previous is None or self._calibration_saved:
            return
        previous, self._previous = self._previous, None
        try:
            self.link.require_disarmed("restoring the unit's previous calibration")
            for name, value in previous.items():
                self.link.write(name, value)
            self.link.save()
        except DutError as exc:
            self._previous = previous
            raise NotRestored(str(exc), {n: f"{NEUTRAL[n]} (was {v})" for n, v in previous.items()
                                         if v != NEUTRAL[n]}) from exc

    # ------------------------------------------------------------------ readings
    def _sensor_ut(self, counts: np.ndarray) -> np.ndarray:
        """INAV's aligned counts (its body axes) into magline's body axes, back into the sensor's by the
        alignment, in µT (under the neutral calibration)."""
        return (self.to_body.T @ (FLIP @ counts)) / self.counts_per_ut

    def samples(self, rate_hz: float) -> Iterator[SampleChunk]:
        """``MSP_RAW_IMU`` polled at ``rate_hz``: a compass reading is passed once (INAV updates it at
        10 Hz; the copies between are dropped and counted), the accelerometer at every poll, both on the
        station's clock at the middle of each request's round trip; an answer that came back late is left
        out (:func:`placed_in_time`)."""
        period = 1.0 / rate_hz
        repeats = RepeatFilter(timed=True)
        start = due = handed = time.monotonic()
        told, least_rtt = 0, float("inf")
        mags: list[np.ndarray] = []
        times: list[float] = []
        accel: list[np.ndarray] = []
        accel_t: list[float] = []
        while True:
            now = time.monotonic()
            if now < due:
                time.sleep(due - now)
            due = max(due + period, time.monotonic() - period)
            asked = time.monotonic()
            reading = self.link.imu()
            answered = time.monotonic()
            least_rtt = min(least_rtt, answered - asked)
            taken = placed_in_time(asked, answered, least_rtt)
            if taken is not None:
                t_ms = (taken - start) * 1000.0
                accel.append(reading.accel_mss)
                accel_t.append(t_ms)
                if repeats.accept(*reading.mag_counts):
                    mags.append(self._sensor_ut(reading.mag_counts))
                    times.append(t_ms)
            # handed on every tenth of a second even when every answer in it came late: the station's own
            # clock (its timeout, an abort) is looked at between chunks
            if answered - handed >= CHUNK_S:
                yield SampleChunk(mag_ut=np.array(mags, float).reshape(-1, 3), t_ms=np.array(times, float),
                                  repeats=repeats.repeats - told,
                                  imu=ImuSeries(t_ms=np.array(accel_t, float),
                                                accel_mss=np.array(accel, float).reshape(-1, 3)) if accel else None)
                told, handed = repeats.repeats, answered
                mags, times, accel, accel_t = [], [], [], []

    # ------------------------------------------------------------------ calibration
    def calibration_params(self, fit: FitResult, sensor: int | None = None) -> dict[str, ParamValue]:
        settings = fit_to_settings(fit, self.counts_per_ut)
        self._field_ut = float(fit.field_ut)
        return dict(settings)

    def orientation_params(self, device_id: int, value: int) -> dict[str, ParamValue]:
        """The settings that make INAV take the compass as mounted in MAV orientation ``value``: for an
        external compass its three angles (all zero would hand it back to align_mag: CW0 then), else
        ``align_mag`` when one of its eight holds it."""
        if self.external:
            roll, pitch, yaw = inav_external_angles(inav_rotation_in_frd(orientation_matrix(value)))
            if not (roll or pitch or yaw):
                return {"align_mag": 1, **dict.fromkeys(EXTERNAL_ANGLES, 0)}
            return dict(zip(EXTERNAL_ANGLES, (roll, pitch, yaw), strict=True))
        alignment = alignment_for(value)
        if alignment is None:
            raise DutError(f"none of INAV's eight align_mag values holds MAV orientation {value}: remount the compass")
        return {"align_mag": alignment}

    def read_params(self, names: list[str]) -> dict[str, ParamValue]:
        return {name: self.link.read(name) for name in names}

    def write_params(self, params: dict[str, ParamValue]) -> dict[str, ParamValue]:
        """Each setting in its own type, after every value was checked against its range and the unit found
        disarmed; the echo is each setting read back (INAV's write reply carries no value)."""
        self.link.require_disarmed("writing the calibration")
        for name, value in params.items():
            self.link.check(name, value)
        for name, value in params.items():
            self.link.write(name, value)
        self._wrote_calibration = self._wrote_calibration or any(n in NEUTRAL for n in params)
        return self.read_params(list(params))

    def commit(self) -> None:
        self.link.require_disarmed("saving the calibration")
        self.link.save()
        if self._wrote_calibration:
            self._calibration_saved, self._wrote_calibration = True, False

    # ------------------------------------------------------------------ power cycle and proof
    def reboot(self) -> None:
        self.link.require_disarmed("the reboot")  # INAV ACKs MSP_REBOOT while armed and does not reboot
        self.link.reboot()
        self.link.close()

    def release_link(self) -> None:
        self.link.close()

    def await_boot(self, since: float) -> dict[str, float]:
        def reconnect(remaining_s: float) -> None:
            self.link.close()
            self.link.open(remaining_s)

        reconnected, uptime = await_new_boot(reconnect, self.link.uptime_s, since, self.opts.boot_timeout_s)
        before, now = self.identity, self.link.identify()
        if before is not None and now.uid != before.uid:
            raise LinkError(f"after the power cycle the board on {self.product.connection} has MCU UID {now.uid}, "
                            f"not the unit under test's ({before.uid}): another board; the unit's calibration is "
                            "not proven")
        self._read_alignment()  # a written align_mag is the compass's from this boot
        self.present = bool(np.any(self.link.imu().mag_counts != 0))  # INAV's compassIsHealthy
        return {"time_to_heartbeat_s": reconnected, "uptime_at_reconnect_s": uptime}

    def uptime_s(self) -> float | None:
        return self.link.uptime_s()

    def selected_sensor_present(self) -> bool:
        return self.present

    def persistence_problems(self) -> list[str]:
        flags = self.link.arming_flags()
        return ["INAV says the compass is not calibrated (arming disabled: COMPASS_NOT_CALIBRATED)"
                ] if flags & COMPASS_NOT_CALIBRATED else []

    def calibrated_field_ut(self, count: int, sensor: int | None = None) -> np.ndarray | None:
        """``count`` of INAV's calibrated readings (body axes) in µT: its output is 1024 counts long in the
        field the written gains were made for; None when this run wrote none."""
        if self._field_ut is None:
            return None
        rows = ReadingsAtRest(count, 2.0 + count * 0.2)  # a 10 Hz compass's distinct readings, twice over
        while not rows.done:
            rows.add(*self.link.imu().mag_counts)  # each poll is an answer: a silent link raises on its own
            time.sleep(0.01)
        return np.array([output_to_ut(counts, self._field_ut) for counts in rows.rows()])
