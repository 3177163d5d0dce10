"""The PX4 backend's options (``products.<part>.options`` in a station file)."""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field


class Px4Options(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True)
    connect_timeout_s: Annotated[float, Field(gt=0)] = 10.0
    boot_timeout_s: Annotated[float, Field(gt=0)] = 30.0  # reboot → heartbeat of the new boot
    stream_timeout_s: Annotated[float, Field(gt=0)] = 2.0  # no sample for this long = link lost
    # Production leaves this on; a test switches it off to show the reboot-before-autosave trap.
    force_save: bool = True
    # PREFLIGHT_STORAGE is ACKed *before* the save runs and PX4 signals no completion: wait this long
    # before anything may cut the power (a commanded reboot waits by itself; a supply does not).
    save_settle_s: Annotated[float, Field(ge=0)] = 1.0
