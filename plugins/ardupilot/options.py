"""The ArduPilot backend's options (``products.<part>.options`` in a station file)."""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field


class ArduPilotOptions(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, defer_build=True)
    connect_timeout_s: Annotated[float, Field(gt=0)] = 10.0
    boot_timeout_s: Annotated[float, Field(gt=0)] = 30.0  # reboot → heartbeat of the new boot
    # a write: 3 tries of this; a read: 5, waiting 1×, 2×, 4×, 4×, 4× this
    param_timeout_s: Annotated[float, Field(gt=0)] = 1.0
    stream_timeout_s: Annotated[float, Field(gt=0)] = 2.0  # no sample for this long = link lost
    prearm_wait_s: Annotated[float, Field(ge=0)] = 1.0  # how long to collect PreArm texts after the check
    # Production leaves this on; a test switches it off to show the "not calibrated after reboot" trap.
    force_save_device_ids: bool = True
