"""The mock DUT's options (``products.<part>.options`` in a station file), validated strictly."""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field

from magline.plugin import StationPath


class MockFaults(BaseModel):
    """Faults a test can switch on to prove the station catches them."""

    model_config = ConfigDict(extra="forbid", strict=True, defer_build=True)
    skip_commit: bool = False
    """The unit's commit returns without writing its storage: the calibration is lost at a power cycle."""
    refuse_writes: list[str] = Field(default_factory=list)
    """Parameters whose write the unit silently ignores."""
    sensor_missing_after_reboot: bool = False
    """The magnetometer is gone after the power cycle."""
    fail_connect: bool = False
    """The unit never answers a connect."""


class MockOptions(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, defer_build=True)
    hard_iron_ut: Annotated[list[float], Field(min_length=3, max_length=3)] = [35.0, -22.0, 61.0]
    """The simulated unit's hard-iron offset, µT, in the sensor's axes."""
    soft_iron: Annotated[list[list[float]], Field(min_length=3, max_length=3)] = [
        [1.06, 0.03, -0.02], [0.03, 0.95, 0.015], [-0.02, 0.015, 1.0]]
    """The simulated unit's soft-iron matrix (rows)."""
    field_ut: float = 48.0
    """The Earth field's magnitude where the simulated unit stands."""
    inclination_deg: float = 62.0
    """The Earth field's dip below the horizontal there."""
    noise_ut: Annotated[float, Field(ge=0)] = 0.3
    """The magnetometer's white noise, 1σ per axis."""
    device_id: int = 396825
    """The magnetometer's device id (396825: an IST8310 on I2C bus 1 at 0x0E, as PX4 encodes it)."""
    soft_iron_model: str = "full"
    """What the simulated firmware can hold: ``diagonal`` (scales only), anything else a full matrix."""
    motions: list[str] = ["single_axis", "hand_tumble"]
    """The motion of each acquisition attempt, the last one repeating: ``single_axis`` (the operator's classic
    mistake, turned about the vertical only), ``hand_tumble``, ``full_sphere``, ``hemisphere``, ``cap30``,
    ``two_rings`` or ``cradle_turns``."""
    single_axis_wobble_deg: float = 15.0
    """The hand's wobble of a ``single_axis`` motion."""
    motion_samples: Annotated[int, Field(ge=50)] = 600
    """Readings of one pass of the motion (it repeats while the station reads on)."""
    realtime: bool = True
    """Stream at the real pace; ``false``: as fast as the station reads (tests)."""
    storage: StationPath = Field(default="mock-dut-storage.json", validate_default=True)
    """The unit's non-volatile memory, a file beside the station file unless absolute: two stations started
    from one folder keep two units' memories."""
    coil_sim: str | None = None
    """The unit stands at the centre of a simulated Helmholtz coil (``magline sim coil``, as ``tcp:HOST:PORT``):
    its field is whatever the coil makes there, asked through the simulator's SIM:FIELD? channel."""
    misalignment_deg: Annotated[list[float], Field(min_length=3, max_length=3)] = [0.0, 0.0, 0.0]
    """Sensor axes rotated against the body (fixture) frame, as a rotation vector: invisible to Earth-field
    tumbling, recovered by the coil's full affine fit."""
    seed: int | None = None
    """The simulated unit's random seed (none: a new unit each time)."""
    accelerometer: bool = True
    """The unit's accelerometer beside the magnetometer (the mounting check's gravity); ``false``: a firmware
    whose stream carries none."""
    faults: MockFaults = Field(default_factory=MockFaults)
    """Faults switched on (below)."""
