"""The mock DUT backend (see the package docstring)."""

from __future__ import annotations

import socket
import time
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from magline.plugin import ImuSeries, LinkError, NotRestored, ParamValue, SampleChunk, UnitInfo
from magline.sim.storage import NvStorage
from magline.sim.truth import GRAVITY_MSS, SensorTruth, earth_field_ned, gravity_body, motion_directions
from magline.sim.truth.motions import ring_attitudes

if TYPE_CHECKING:
    from magline.plugin import FitResult
    from magline.plugins.mock.options import MockOptions

# The mock's own parameter names: offsets in µT (subtracted), the symmetric matrix S entries.
OFFSETS = ("MAG_OFS_X", "MAG_OFS_Y", "MAG_OFS_Z")
MATRIX = (("MAG_S11", 0, 0), ("MAG_S22", 1, 1), ("MAG_S33", 2, 2),
          ("MAG_S12", 0, 1), ("MAG_S13", 0, 2), ("MAG_S23", 1, 2))
DEFAULTS: dict[str, ParamValue] = {**dict.fromkeys(OFFSETS, 0.0), "MAG_S11": 1.0, "MAG_S22": 1.0,
                                   "MAG_S33": 1.0, "MAG_S12": 0.0, "MAG_S13": 0.0, "MAG_S23": 0.0,
                                   "MAG_DEV_ID": 0, "MAG_AUTOCAL": 1}
CHUNK = 10
ACCEL_NOISE_MSS = 0.02  # a MEMS accelerometer's noise at these rates


class MockDut:
    def __init__(self, options: MockOptions) -> None:
        self.opts = options
        self.rng = np.random.default_rng(options.seed)
        self.truth = SensorTruth(hard_iron_ut=np.array(options.hard_iron_ut),
                                 soft_iron=np.array(options.soft_iron), noise_ut=options.noise_ut)
        self.field_ned = earth_field_ned(options.field_ut, options.inclination_deg)
        # sensor frame = body frame rotated by the misalignment: the sensor sees Rᵀ·b
        from scipy.spatial.transform import Rotation  # on use: SciPy's import costs every command's start

        self.to_sensor = Rotation.from_rotvec(np.deg2rad(options.misalignment_deg)).inv()
        self.storage = NvStorage(Path(options.storage))
        self.ram: dict[str, ParamValue] = {}
        self.acquisitions = 0
        self.connected = False
        self.sensor_present = True
        self._saved_autocal: ParamValue | None = None

    # ------------------------------------------------------------------ link
    def connect(self) -> UnitInfo:
        if self.opts.faults.fail_connect:
            raise LinkError("mock DUT does not answer (fault injected)")
        self._boot()
        return UnitInfo(autopilot="mock", firmware="1.0.0", sensors=[self.opts.device_id],
                        selected_sensor=self.opts.device_id,
                        soft_iron_model="diagonal" if self.opts.soft_iron_model == "diagonal" else "full",
                        extra={"storage": str(self.storage.path)})

    def _boot(self) -> None:
        self.ram = {**DEFAULTS, **self.storage.load()}
        self.connected = True
        self._booted_at = time.monotonic()

    def uptime_s(self) -> float:
        """Seconds since this mock last booted (connect or power cycle), as an autopilot's SYSTEM_TIME says."""
        self._require_link()
        return time.monotonic() - self._booted_at

    def prepare(self) -> None:
        self._saved_autocal = self.ram["MAG_AUTOCAL"]
        self.ram["MAG_AUTOCAL"] = 0

    def restore(self) -> None:
        if self._saved_autocal is None:
            return
        if not self.connected:
            raise NotRestored("link to mock DUT lost", {"MAG_AUTOCAL": f"0 (was {self._saved_autocal})"})
        self.ram["MAG_AUTOCAL"] = self._saved_autocal
        # in storage too: the calibration's commit saved MAG_AUTOCAL = 0 along with everything else
        stored = self.storage.load()
        if stored.get("MAG_AUTOCAL", self._saved_autocal) != self._saved_autocal:
            stored["MAG_AUTOCAL"] = self._saved_autocal
            self.storage.save(stored)
        self._saved_autocal = None

    def close(self) -> None:
        self.connected = False

    # ------------------------------------------------------------------ data
    def samples(self, rate_hz: float) -> Iterator[SampleChunk]:
        """Raw samples while the simulated operator moves the unit (motion chosen per attempt), or,
        in a coil, while it stands still in whatever field the coil makes."""
        field_chunks = self._coil_field_chunks() if self.opts.coil_sim else self._motion_field_chunks()
        t0 = time.monotonic()
        sent = 0
        for block, gravity in field_chunks:
            if not self.connected:
                raise LinkError("link to mock DUT lost")
            raw = self.truth.read(self.to_sensor.apply(block), self.rng)
            t_ms = (sent + np.arange(len(raw))) * 1000.0 / rate_hz
            sent += len(raw)
            if self.opts.realtime:
                delay = t0 + sent / rate_hz - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
            yield SampleChunk(mag_ut=raw, t_ms=t_ms, imu=self._imu(block, gravity, t_ms))

    def _imu(self, fields_body: np.ndarray, gravity: np.ndarray | None, t_ms: np.ndarray) -> ImuSeries | None:
        """The accelerometer at the same instants: gravity in body axes of the motion's own attitude where
        it has one (a spin's gravity stays put), else of an attitude that turns the Earth field into each of
        the block's body-frame fields (the smallest such turn from level), with the accelerometer's own noise.
        A unit standing in a coil sees gravity never change."""
        if not self.opts.accelerometer:
            return None
        if self.opts.coil_sim:
            gravity = np.tile([0.0, 0.0, -GRAVITY_MSS], (len(fields_body), 1))
        elif gravity is None:
            gravity = gravity_body(fields_body, self.field_ned)
        return ImuSeries(t_ms=t_ms, accel_mss=gravity + self.rng.normal(0.0, ACCEL_NOISE_MSS, gravity.shape))

    def _motion_field_chunks(self) -> Iterator[tuple[np.ndarray, np.ndarray | None]]:
        motion = self.opts.motions[min(self.acquisitions, len(self.opts.motions) - 1)]
        self.acquisitions += 1
        while True:
            directions, gravity = self._motion(motion)
            fields = directions * self.opts.field_ut
            for start in range(0, len(fields), CHUNK):
                yield fields[start:start + CHUNK], None if gravity is None else gravity[start:start + CHUNK]

    def _coil_field_chunks(self) -> Iterator[tuple[np.ndarray, None]]:
        _, host, port = str(self.opts.coil_sim).split(":")
        try:
            link = socket.create_connection((host, int(port)), timeout=2.0)
        except OSError as exc:
            raise LinkError(f"mock DUT: coil simulator {self.opts.coil_sim} not reachable: {exc}") from exc
        with link, link.makefile("rw", encoding="ascii", newline="\n") as wire:
            while True:
                wire.write("SIM:FIELD?\n")
                wire.flush()
                field = np.array([float(v) for v in wire.readline().split(",")])
                yield np.tile(field, (CHUNK, 1)), None

    def _motion(self, name: str) -> tuple[np.ndarray, np.ndarray | None]:
        """The field's directions in the body, and gravity's (m/s², pointing up) where the motion has an
        attitude of its own."""
        n = self.opts.motion_samples
        if name == "single_axis":  # turned about the vertical: the field circles, gravity stays
            attitudes = ring_attitudes(n, self.rng, np.array([0.0, 0.0, 1.0]), self.opts.single_axis_wobble_deg)
            field_dir = self.field_ned / np.linalg.norm(self.field_ned)
            return attitudes.inv().apply(field_dir), attitudes.inv().apply([0.0, 0.0, -GRAVITY_MSS])
        return motion_directions(name, n, self.rng, self.field_ned), None

    # ------------------------------------------------------------------ parameters
    def calibration_params(self, fit: FitResult) -> dict[str, ParamValue]:
        params: dict[str, ParamValue] = {name: float(v) for name, v in zip(OFFSETS, fit.hard_iron_ut, strict=True)}
        # the mock firmware computes S·(m − h) with |m_cal| in its own gain: normalise to unit field
        s = fit.soft_iron / fit.field_ut * self.opts.field_ut
        params.update({name: float(s[i, j]) for name, i, j in MATRIX})
        params["MAG_DEV_ID"] = int(self.opts.device_id)
        return params

    def read_params(self, names: list[str]) -> dict[str, ParamValue]:
        self._require_link()
        return {n: self.ram[n] for n in names if n in self.ram}

    def write_params(self, params: dict[str, ParamValue]) -> dict[str, ParamValue]:
        self._require_link()
        echoed: dict[str, ParamValue] = {}
        for name, value in params.items():
            if name not in self.ram:
                continue  # unknown names are ignored, as autopilots do
            if name in self.opts.faults.refuse_writes:
                echoed[name] = self.ram[name]
                continue
            self.ram[name] = int(value) if isinstance(self.ram[name], int) else float(np.float32(value))
            echoed[name] = self.ram[name]
        return echoed

    def commit(self) -> None:
        self._require_link()
        if not self.opts.faults.skip_commit:
            self.storage.save(self.ram)

    def reboot(self) -> None:
        self.release_link()

    def release_link(self) -> None:
        self.connected = False
        self.ram = {}

    def await_boot(self, since: float) -> dict[str, float]:
        if self.opts.faults.sensor_missing_after_reboot:
            self.sensor_present = False
        self._boot()
        return {"time_to_heartbeat_s": time.monotonic() - since}

    def selected_sensor_present(self) -> bool:
        return self.sensor_present

    def persistence_problems(self) -> list[str]:
        return []

    def calibrated_field_ut(self, count: int) -> np.ndarray:
        """What the mock firmware outputs with the calibration it holds now, at ``count`` attitudes."""
        self._require_link()
        directions = self.rng.normal(size=(count, 3))
        field = directions / np.linalg.norm(directions, axis=1, keepdims=True) * self.opts.field_ut
        raw = self.truth.read(self.to_sensor.apply(field), self.rng)
        s = np.eye(3)
        for name, i, j in MATRIX:
            s[i, j] = s[j, i] = float(self.ram[name])
        return (raw - np.array([self.ram[n] for n in OFFSETS], float)) @ s.T

    def _require_link(self) -> None:
        if not self.connected:
            raise LinkError("mock DUT link is down")
