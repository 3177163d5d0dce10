"""Per-unit state handed to every phase hook.

Why a context object: hooks get one argument that carries the station, the product, the live DUT
and the listeners, so hook signatures stay stable as phases learn more.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from magline.core.fit.samples_csv import RawSamples

if TYPE_CHECKING:
    from magline.core.dut import DutBackend, UnitInfo
    from magline.core.field import FieldSource
    from magline.core.plugins import Plugins
    from magline.core.power import PowerControl
    from magline.core.record import PhaseResult, RunRecord
    from magline.core.station.schema import Limit, Product, Station


@dataclass
class Acquisition:
    """One acquisition attempt: raw samples and the live coverage they reached."""

    attempt: int
    samples: RawSamples
    coverage: float
    target: float

    @property
    def sufficient(self) -> bool:
        return self.coverage >= self.target


class AcquisitionAborted(RuntimeError):
    """The DUT failed mid-acquisition; carries what arrived so the raw data is still recorded."""

    def __init__(self, message: str, partial: Acquisition) -> None:
        super().__init__(message)
        self.partial = partial


@dataclass
class RunContext:
    station: Station
    station_dir: Path
    part: str
    product: Product
    serial: str
    operator: str
    plugins: Plugins
    record: RunRecord
    limits: dict[str, Limit]
    reference_field_ut: float | None = None
    field_source: FieldSource | None = None
    dut: DutBackend | None = None
    power: PowerControl | None = None
    unit: UnitInfo | None = None
    attempts: list[Acquisition] = field(default_factory=list)
    # why the next acquisition attempt is needed, in the operator's terms (None: low coverage)
    retry_advice: str | None = None
    state: dict[str, Any] = field(default_factory=dict)  # scratch space for plugins
    _phase: PhaseResult | None = None

    def log(self, message: str) -> None:
        """Add a line to the current phase's log (kept in the record)."""
        if self._phase is not None:
            self._phase.log.append(message)

    def prompt(self, message: str) -> None:
        self.log(f"operator: {message}")
        self.plugins.hook.magline_operator_prompt(run=self, message=message)

    def progress(self, attempt: int, samples: int, coverage: float, target: float) -> None:
        self.plugins.hook.magline_acquisition_progress(run=self, attempt=attempt, samples=samples,
                                                       coverage=coverage, target=target)

    def require_power(self) -> PowerControl:
        if self.power is None:
            raise RuntimeError("no power control is set up")
        return self.power

    def require_dut(self) -> DutBackend:
        if self.dut is None:
            raise RuntimeError("no DUT is connected")
        return self.dut
