"""The options of the core's field sources, ``fixed`` and ``wmm`` (``field_source.options`` in a station file).

Why models: ``magline check`` validates a registered model's options with file, key and line; without one a
misspelt option passed the check and stopped the run at its start (a mistyped magnitude as a traceback), and
the most used field source had no table in the options reference.
"""

from __future__ import annotations

import datetime as dt
from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field


class ReferenceOptions(BaseModel):
    """``field_source.options.reference`` in a station file: the fluxgate (:mod:`.reference`) that checks the field.

    Here, apart from the instrument's code, so that checking a station file imports none of that."""

    model_config = ConfigDict(extra="forbid", strict=True, defer_build=True)
    resource: str
    """The DAQ the fluxgate's outputs are wired to, e.g. TCPIP0::10.0.0.7::5025::SOCKET."""
    channels: str = "(@101,102,103)"
    """The fluxgate's X, Y, Z outputs on the DAQ."""
    scale_ut_per_v: Annotated[float, Field(gt=0)] = 10.0
    """The fluxgate's scale (±10 V = ±100 µT is common)."""
    tolerance_ut: Annotated[float, Field(gt=0)] = 1.5
    """How far the measured field may sit from the model's (|reference − model|)."""
    drift_limit_ut: Annotated[float, Field(gt=0)] = 0.5
    """How far the measured magnitude may drift from the batch's first check."""
    every_n_units: Annotated[int, Field(ge=1)] = 10
    """The field is checked at the first unit and every this many units after."""
    readings: Annotated[int, Field(ge=1)] = 5
    """Readings averaged per check."""
    timeout_s: Annotated[float, Field(gt=0)] = 2.0
    """One instrument's reply."""


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
