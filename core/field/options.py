"""The options of the core's field sources, ``fixed`` and ``wmm`` (``field_source.options`` in a station file).

Why models: ``magline check`` validates a registered model's options with file, key and line; without one a
misspelt option passed the check and stopped the run at its start (a mistyped magnitude as a traceback), and
the most used field source had no table in the options reference.
"""

from __future__ import annotations

import datetime as dt
from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field

from magline.core.field.reference import ReferenceOptions


class FixedFieldOptions(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, defer_build=True)
    field_ut: Annotated[float, Field(ge=1.0, le=1000.0)]
    """The field's magnitude at the fixture, µT, as surveyed: the radius every calibrated sphere must have."""
    inclination_deg: Annotated[float, Field(ge=-90.0, le=90.0)] | None = None
    """The surveyed dip, degrees, positive down: the mounting check judges the inclination each magnetometer
    sees against it (without it, the inclination is measured but not judged)."""
    reference: ReferenceOptions | None = None
    """A live fluxgate that checks the cell's field at the batch's start and every few units."""


class WmmOptions(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, defer_build=True)
    date: Annotated[dt.date, Field(strict=False)] | None = None
    """The day the model is evaluated for (ISO, 2026-03-01); without it, the day the station starts.  A day
    outside the model's validity warns and uses the nearest valid one."""
    reference: ReferenceOptions | None = None
    """A live fluxgate that checks the model's field at the batch's start and every few units."""
