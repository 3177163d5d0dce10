"""The PX4 backend's options (``products.<part>.options`` in a station file)."""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field


class Px4Options(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, defer_build=True)
    connect_timeout_s: Annotated[float, Field(gt=0)] = 10.0
    """The board's first heartbeat within this, else the unit is an ERROR in connect."""
    boot_timeout_s: Annotated[float, Field(gt=0)] = 30.0
    """A reboot → the heartbeat of the new boot."""
    stream_timeout_s: Annotated[float, Field(gt=0)] = 2.0
    """No sample for this long: the link is lost."""
    force_save: bool = True
    """Save the parameters at once rather than trust PX4's autosave (production leaves this on; a test switches
    it off to show the reboot-before-autosave trap)."""
    save_settle_s: Annotated[float, Field(ge=0)] = 1.0
    """How long nothing may cut the power after a save: PREFLIGHT_STORAGE is acknowledged *before* the save
    runs and PX4 signals no completion (a commanded reboot waits by itself; a supply does not)."""
    sensor_instance: Annotated[int, Field(ge=0, le=2)] | None = None
    """Without an answering MAVLink shell (POSIX builds, a busy or disabled shell): which sensor_mag instance
    (SCALED_IMU 0, SCALED_IMU2 1, SCALED_IMU3 2) the product's magnetometer is, when the unit streams more
    than one; with one stream it is not needed."""
    shell_timeout_s: Annotated[float, Field(gt=0)] = 2.0
    """A MAVLink shell that says nothing by then is not used."""
    stream_probe_s: Annotated[float, Field(gt=0)] = 1.0
    """How long each SCALED_IMU stream is watched to tell which sensor it carries."""
    factory_store_timeout_s: Annotated[float, Field(gt=0)] = 30.0
    """``persist: factory-storage``: how long the gyro calibration that writes the factory store may take."""
