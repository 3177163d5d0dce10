"""The ArduPilot backend's options (``products.<part>.options`` in a station file)."""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field


class ArduPilotOptions(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, defer_build=True)
    connect_timeout_s: Annotated[float, Field(gt=0)] = 10.0
    """The board's first heartbeat within this, else the unit is an ERROR in connect."""
    boot_timeout_s: Annotated[float, Field(gt=0)] = 30.0
    """A reboot → the heartbeat of the new boot."""
    param_timeout_s: Annotated[float, Field(gt=0)] = 1.0
    """One parameter's answer: a write is tried 3 times, a read 5 (waiting 1×, 2×, 4×, 4×, 4× this)."""
    stream_timeout_s: Annotated[float, Field(gt=0)] = 2.0
    """No sample for this long: the link is lost."""
    prearm_wait_s: Annotated[float, Field(ge=0)] = 1.0
    """How long the compass's PreArm texts are collected after the check is asked for."""
    force_save_device_ids: bool = True
    """Force-save the compass device ids with the calibration (without it ArduPilot reports the compass not
    calibrated after a reboot).  Production leaves this on; a test switches it off to show that trap."""
