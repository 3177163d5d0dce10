"""The Helmholtz field source's options (``field_source.options`` of a coil station)."""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field, model_validator

from magline.plugin import ReferenceOptions


class HelmholtzOptions(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, defer_build=True)
    # Either one three-channel controller (``resource``) or three bipolar single-channel sources,
    # one per axis x, y, z (``resources``), e.g. TCPIP0::10.0.0.9::5025::SOCKET
    resource: str | None = None
    resources: Annotated[list[str], Field(min_length=3, max_length=3)] | None = None
    constants_ut_per_a: Annotated[list[float], Field(min_length=3, max_length=3)]  # per axis, from the coil's data
    max_current_a: Annotated[float, Field(gt=0)] = 1.0
    field_ut: Annotated[float, Field(gt=0, le=500)] = 50.0  # magnitude of the applied vectors
    directions: Annotated[int, Field(ge=7, le=500)] = 26  # well spread directions (Fibonacci sphere)
    zero_steps: Annotated[int, Field(ge=0, le=10)] = 1  # zero-field steps (they pin the offset directly)
    settle_s: Annotated[float, Field(ge=0)] = 0.1  # after each step, before the DUT is read
    samples_per_step: Annotated[int, Field(ge=1)] = 10
    current_tolerance_a: Annotated[float, Field(gt=0)] = 0.005  # read-back vs set, per channel
    reference: ReferenceOptions  # the fluxgate at the coil centre: nulling and verification
    null_tolerance_ut: Annotated[float, Field(gt=0)] = 0.05
    null_iterations: Annotated[int, Field(ge=1, le=50)] = 8
    warmup_s: Annotated[float, Field(ge=0)] = 2.0  # the field at full current must be stable over this
    warmup_limit_ut: Annotated[float, Field(gt=0)] = 0.2
    verify_tolerance_pct: Annotated[float, Field(gt=0)] = 1.0  # each axis at field_ut against the fluxgate
    timeout_s: Annotated[float, Field(gt=0)] = 2.0

    @model_validator(mode="after")
    def _one_kind_of_source(self) -> HelmholtzOptions:
        if (self.resource is None) == (self.resources is None):
            raise ValueError("give either resource (one 3-channel controller) or resources (three sources, x y z)")
        return self
