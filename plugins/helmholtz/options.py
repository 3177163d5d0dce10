"""The Helmholtz field source's options (``field_source.options`` of a coil station)."""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field, model_validator

from magline.plugin import ReferenceOptions


class HelmholtzOptions(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, defer_build=True)
    resource: str | None = None
    """One three-channel current controller, e.g. TCPIP0::10.0.0.9::5025::SOCKET (or ``resources``)."""
    resources: Annotated[list[str], Field(min_length=3, max_length=3)] | None = None
    """Three bipolar single-channel sources, one per axis x, y, z (or ``resource``)."""
    constants_ut_per_a: Annotated[list[float], Field(min_length=3, max_length=3)]
    """Each axis's field per ampere, µT/A, from the coil's data."""
    max_current_a: Annotated[float, Field(gt=0)] = 1.0
    """The most current any channel is asked for."""
    field_ut: Annotated[float, Field(gt=0, le=500)] = 50.0
    """The magnitude of the applied field vectors."""
    directions: Annotated[int, Field(ge=7, le=500)] = 26
    """How many well spread directions are applied (a Fibonacci sphere)."""
    zero_steps: Annotated[int, Field(ge=0, le=10)] = 1
    """Zero-field steps among them: they pin the offset directly."""
    settle_s: Annotated[float, Field(ge=0)] = 0.1
    """After each step, before the unit is read."""
    samples_per_step: Annotated[int, Field(ge=1)] = 10
    """Readings of the unit taken at each step."""
    current_tolerance_a: Annotated[float, Field(gt=0)] = 0.005
    """Each channel's read-back current against the current set."""
    reference: ReferenceOptions
    """The fluxgate at the coil's centre: it nulls the ambient field and verifies the coil (below)."""
    null_tolerance_ut: Annotated[float, Field(gt=0)] = 0.05
    """The ambient field left at the centre once nulled."""
    null_iterations: Annotated[int, Field(ge=1, le=50)] = 8
    """Nulling steps tried before the coil is an ERROR."""
    warmup_s: Annotated[float, Field(ge=0)] = 2.0
    """The field at full current must be stable over this."""
    warmup_limit_ut: Annotated[float, Field(gt=0)] = 0.2
    """How much that field may change over ``warmup_s``."""
    verify_tolerance_pct: Annotated[float, Field(gt=0)] = 1.0
    """Each axis at ``field_ut`` against the fluxgate."""
    timeout_s: Annotated[float, Field(gt=0)] = 2.0
    """One instrument's reply."""

    @model_validator(mode="after")
    def _one_kind_of_source(self) -> HelmholtzOptions:
        if (self.resource is None) == (self.resources is None):
            raise ValueError("give either resource (one 3-channel controller) or resources (three sources, x y z)")
        return self
