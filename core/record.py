"""The record of one unit's run: what the results store keeps and quality engineers trace.

Why plain dataclasses: the record is built incrementally by the sequencer (attempts are stored
before fitting), serialised by sinks, and read back by ``magline history``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import UTC, datetime
from enum import StrEnum
from typing import Any

from magline.core.dut import ParamValue
from magline.core.measurements import Attachment, Measurement


class Outcome(StrEnum):
    PASS = "pass"
    FAIL = "fail"
    ERROR = "error"
    SKIPPED = "skipped"


def now_iso() -> str:
    return datetime.now(UTC).isoformat(timespec="milliseconds")


@dataclass
class PhaseResult:
    name: str
    outcome: Outcome = Outcome.SKIPPED
    duration_s: float = 0.0
    log: list[str] = field(default_factory=list)
    message: str = ""


@dataclass
class AttemptRecord:
    attempt: int
    samples: int
    coverage: float
    target: float
    raw_csv: str
    accepted: bool = False
    refused: str | None = None  # why the fit could not use these samples, when it could not


@dataclass
class PersistReport:
    before: dict[str, ParamValue]
    written: dict[str, ParamValue]
    echoed: dict[str, ParamValue]


@dataclass
class VerifyReport:
    read_back: dict[str, ParamValue]
    mismatches: list[str]
    sensor_present: bool
    method: str
    figures: dict[str, float] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.sensor_present and not self.mismatches


@dataclass
class RunRecord:
    serial: str
    part: str
    station_id: str
    line: str
    operator: str
    software_version: str
    limit_hash: str
    started: str = field(default_factory=now_iso)
    finished: str | None = None
    verdict: Outcome = Outcome.ERROR
    cause: str = ""
    unit_info: dict[str, Any] = field(default_factory=dict)
    phases: list[PhaseResult] = field(default_factory=list)
    attempts: list[AttemptRecord] = field(default_factory=list)
    measurements: list[Measurement] = field(default_factory=list)
    calibration: dict[str, Any] | None = None
    params_before: dict[str, ParamValue] = field(default_factory=dict)
    params_written: dict[str, ParamValue] = field(default_factory=dict)
    params_read_back: dict[str, ParamValue] = field(default_factory=dict)
    persistence: dict[str, Any] = field(default_factory=dict)
    attachments: list[Attachment] = field(default_factory=list)
    run_id: int | None = None
