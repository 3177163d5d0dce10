"""The PX4 backend's options (``products.<part>.options`` in a station file)."""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field


class Px4Options(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, defer_build=True)
    connect_timeout_s: Annotated[float, Field(gt=0)] = 10.0
    boot_timeout_s: Annotated[float, Field(gt=0)] = 30.0  # reboot → heartbeat of the new boot
    stream_timeout_s: Annotated[float, Field(gt=0)] = 2.0  # no sample for this long = link lost
    # Production leaves this on; a test switches it off to show the reboot-before-autosave trap.
    force_save: bool = True
    # PREFLIGHT_STORAGE is ACKed *before* the save runs and PX4 signals no completion: wait this long
    # before anything may cut the power (a commanded reboot waits by itself; a supply does not).
    save_settle_s: Annotated[float, Field(ge=0)] = 1.0
    # Without an answering MAVLink shell (POSIX builds, a busy or disabled shell), which sensor_mag
    # instance (SCALED_IMU 0, SCALED_IMU2 1, SCALED_IMU3 2) the product's magnetometer is, when the
    # unit streams more than one; with one stream it is not needed.
    sensor_instance: Annotated[int, Field(ge=0, le=2)] | None = None
    shell_timeout_s: Annotated[float, Field(gt=0)] = 2.0  # a shell that says nothing by then is not used
    stream_probe_s: Annotated[float, Field(gt=0)] = 1.0  # how long each SCALED_IMU stream is watched
    # persist: factory-storage — how long the gyro calibration that writes the factory store may take
    factory_store_timeout_s: Annotated[float, Field(gt=0)] = 30.0
