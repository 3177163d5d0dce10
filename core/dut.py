"""What a DUT backend is: the autopilot-specific half of a calibration.

Why a Protocol rather than hooks for every call: a backend holds a live link (a MAVLink socket,
an in-process simulator) whose state spans the whole run, so it is an object created per unit by
the factory a plugin registers through ``magline_register_dut_backends``.  The core's default
phase hooks drive it; a plugin can still replace a whole phase through the phase hooks.

Units: everything crossing this interface is in µT and the fit's convention
``m_cal = S·(m_raw − h)``; conversion to Gauss / milligauss and to the autopilot's sign
convention happens inside :meth:`DutBackend.calibration_params`.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal, Protocol, TypeVar, runtime_checkable

from numpy.typing import NDArray
from pydantic import BaseModel, ValidationError

if TYPE_CHECKING:
    from magline.core.fit import FitResult
    from magline.core.station.schema import Product

ParamValue = int | float


class DutError(RuntimeError):
    """A DUT-side failure (link lost, parameter refused, sensor missing) with its cause."""


@dataclass
class UnitInfo:
    """Who answered on the link."""

    autopilot: str
    firmware: str
    sensors: list[int]  # device ids of the magnetometers present
    selected_sensor: int  # device id being calibrated
    soft_iron_model: Literal["full", "diagonal"] = "full"  # what the autopilot can hold
    extra: dict[str, Any] = field(default_factory=dict)


@dataclass
class SampleChunk:
    """Raw samples of the selected magnetometer, µT, with their time stamps (ms)."""

    mag_ut: NDArray
    t_ms: NDArray
    temp_c: NDArray | None = None


@runtime_checkable
class DutBackend(Protocol):
    def connect(self) -> UnitInfo:
        """Open the link, identify the autopilot and its magnetometers."""

    def prepare(self) -> None:
        """Stop the firmware rewriting calibration during the test; remember what to restore."""

    def samples(self, rate_hz: float) -> Iterator[SampleChunk]:
        """Stream raw (uncalibrated) samples until the caller stops iterating."""

    def calibration_params(self, fit: FitResult) -> dict[str, ParamValue]:
        """Map a fit to this autopilot's parameters (units and sign convention applied here)."""

    def read_params(self, names: list[str]) -> dict[str, ParamValue]:
        """Read parameters from the DUT."""

    def write_params(self, params: dict[str, ParamValue]) -> dict[str, ParamValue]:
        """Write parameters; return the values the DUT echoed (raise DutError when refused)."""

    def commit(self) -> None:
        """Force the parameters to non-volatile storage."""

    def reboot(self) -> None:
        """Command a reboot over the link (what the ``mavlink-reboot`` power method uses)."""

    def release_link(self) -> None:
        """Close the link: the power is about to be cut and the vehicle will vanish."""

    def await_boot(self, since: float) -> dict[str, float]:
        """Reconnect after a reboot or power-on at ``since`` (``time.monotonic()``) and prove it is a
        new boot; return figures (``time_to_heartbeat_s``, ``uptime_at_reconnect_s``)."""

    def selected_sensor_present(self) -> bool:
        """After a power cycle: is the calibrated sensor still there with the same id?"""

    def persistence_problems(self) -> list[str]:
        """After a power cycle: what the autopilot itself says is wrong with the calibration
        (ArduPilot: "Compass not calibrated" when the device id was not saved); empty when fine."""

    def restore(self) -> None:
        """Put back what :meth:`prepare` changed (called at the end of every run, also on errors)."""

    def close(self) -> None:
        """Release the link."""


DutFactory = Callable[["Product"], DutBackend]

OptionsModel = TypeVar("OptionsModel", bound=BaseModel)


def await_new_boot(reconnect: Callable[[float], None], uptime_s: Callable[[], float | None], started: float,
                   timeout_s: float, poll_s: float = 0.3) -> tuple[float, float]:
    """After a reboot / power-on at ``started`` (monotonic), reconnect until the vehicle proves a new boot.

    Why the uptime check: right after the command the old boot may still answer (PX4 waits 400 ms,
    a UDP link never closes), and a read-back from it would prove nothing.  A boot whose uptime is
    shorter than the time since the command is the new one.  ``reconnect(remaining_s)`` opens a
    fresh link or raises :class:`DutError`; ``uptime_s()`` returns the vehicle's uptime or ``None``.
    Returns (seconds from the command to the new boot's link, its uptime then).
    """
    deadline = started + timeout_s
    while True:
        time.sleep(poll_s)
        try:
            reconnect(max(deadline - time.monotonic(), 0.1))
        except DutError as exc:
            raise DutError(f"the vehicle did not come back within {timeout_s:g} s of the power cycle "
                           f"(last attempt: {exc})") from None
        reconnected = time.monotonic() - started
        uptime = uptime_s()
        if uptime is not None and uptime < reconnected:
            return reconnected, uptime
        if time.monotonic() > deadline:
            raise DutError(f"the vehicle still runs its old boot {timeout_s:g} s after the reboot command "
                           "(reboot refused?)")


def validated_options(model: type[OptionsModel], options: dict[str, Any], owner: str) -> OptionsModel:
    """Validate a plugin's ``options`` from the station file; the error names every bad key."""
    try:
        return model.model_validate(options)
    except ValidationError as exc:
        problems = "; ".join(f"options.{'.'.join(map(str, e['loc']))}: {e['msg']}" for e in exc.errors())
        raise ValueError(f"{owner}: {problems}") from exc
