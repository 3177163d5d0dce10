"""The mock DUT's options (``products.<part>.options`` in a station file), validated strictly."""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field

from magline.plugin import StationPath


class MockFaults(BaseModel):
    """Faults a test can switch on to prove the station catches them."""

    model_config = ConfigDict(extra="forbid", strict=True, defer_build=True)
    skip_commit: bool = False  # commit() returns without writing storage: lost on power cycle
    refuse_writes: list[str] = Field(default_factory=list)  # params whose write is silently ignored
    sensor_missing_after_reboot: bool = False
    fail_connect: bool = False


class MockOptions(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, defer_build=True)
    hard_iron_ut: Annotated[list[float], Field(min_length=3, max_length=3)] = [35.0, -22.0, 61.0]
    soft_iron: Annotated[list[list[float]], Field(min_length=3, max_length=3)] = [
        [1.06, 0.03, -0.02], [0.03, 0.95, 0.015], [-0.02, 0.015, 1.0]]
    field_ut: float = 48.0
    inclination_deg: float = 62.0
    noise_ut: Annotated[float, Field(ge=0)] = 0.3
    device_id: int = 396825  # IST8310 on I2C bus 1 at 0x0E, as PX4 encodes it
    soft_iron_model: str = "full"
    motions: list[str] = ["single_axis", "hand_tumble"]  # per attempt; the last one repeats
    single_axis_wobble_deg: float = 15.0
    motion_samples: Annotated[int, Field(ge=50)] = 600
    realtime: bool = True
    # the unit's non-volatile memory, a file beside the station file unless absolute: two stations started
    # from one folder keep two units' memories
    storage: StationPath = Field(default="mock-dut-storage.json", validate_default=True)
    # The unit stands at the centre of a simulated Helmholtz coil (``magline sim coil``): its field is
    # whatever the coil makes there, asked through the simulator's SIM:FIELD? channel.
    coil_sim: str | None = None
    # Sensor axes rotated against the body (fixture) frame: invisible to Earth-field tumbling,
    # recovered by the coil's full affine fit.
    misalignment_deg: Annotated[list[float], Field(min_length=3, max_length=3)] = [0.0, 0.0, 0.0]
    seed: int | None = None
    # the unit's accelerometer beside the magnetometer (the mounting check's gravity); false: a
    # firmware whose stream carries none
    accelerometer: bool = True
    faults: MockFaults = Field(default_factory=MockFaults)
