"""The INAV backend's options (``products.<part>.options`` in a station file)."""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field


class InavOptions(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, defer_build=True)
    connect_timeout_s: Annotated[float, Field(gt=0)] = 10.0
    """The board answers MSP within this, else the unit is an ERROR in connect."""
    boot_timeout_s: Annotated[float, Field(gt=0)] = 20.0
    """MSP_REBOOT → the new boot answers (SITL: 3–7 s)."""
    reply_timeout_s: Annotated[float, Field(gt=0)] = 1.0
    """One MSP request's reply, else it is sent again."""
    reply_resends: Annotated[int, Field(ge=0, le=10)] = 2
    """An unanswered request is sent again this many times (as INAV's configurator does) before the link is
    called lost: a frame spoilt on a serial line or a board busy writing its flash is not a lost unit."""
    counts_per_gauss: Annotated[float, Field(gt=0)] = 3000.0
    """The compass's counts per gauss as INAV's driver reads it (MSP carries counts; magline works in µT):
    3000 for a QMC5883L at ±8 G (INAV's driver's range); an HMC5883L at its default gain reads 1090."""
