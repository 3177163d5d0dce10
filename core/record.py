"""The record of one unit's run: what the results store keeps and quality engineers trace.

Why plain dataclasses: the record is built incrementally by the sequencer (attempts are stored
before fitting), serialised by sinks, and read back by ``magline history``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import UTC, datetime
from enum import StrEnum
from typing import TYPE_CHECKING, Any

from magline.core.dut import ParamValue
from magline.core.measurements import Attachment, Measurement

if TYPE_CHECKING:
    from magline.core.fit.samples_csv import RawSamples


class Outcome(StrEnum):
    """A phase's or a unit's outcome.  FAIL: the unit was judged bad.  ERROR: the station could not
    judge it.  ABORTED: the operator stopped it.  INCOMPLETE: only in a store — the process writing
    the record died before it finished (see :mod:`magline.core.faults`)."""

    PASS = "pass"
    FAIL = "fail"
    ERROR = "error"
    ABORTED = "aborted"
    SKIPPED = "skipped"
    INCOMPLETE = "incomplete"


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
    raw: RawSamples  # every distinct reading of the attempt, in µT
    accepted: bool = False
    refused: str | None = None  # why these samples were not used: low coverage, the fit's refusal, interrupted
    repeats: int = 0  # copies of readings the stream carried and the backend dropped
    sensor_rate_hz: float | None = None  # distinct readings per second actually received
    more: dict[int, RawSamples] = field(default_factory=dict)  # the other magnetometers' readings, by device id
    imu: Any = None  # the accelerometer's readings (an ImuSeries), when the stream has them
    stopped: str | None = None  # why the tumble ended: "determined", "samples", "stream ended"
    tumble_s: float | None = None  # seconds of tumbling
    # the running fit's σ when determined, and the mounting's errors the stop judged clear of their limits
    predicted: dict[str, dict[str, float]] = field(default_factory=dict)


@dataclass
class PersistReport:
    before: dict[str, ParamValue]
    written: dict[str, ParamValue]
    echoed: dict[str, ParamValue]
    # where the calibration is kept (the product's ``persist``) and, for the factory store, what writing it
    # did: {"written": bool, "said": the firmware's words or why it was not written, "mode_after": int}
    store: str = "parameters"
    factory: dict[str, Any] | None = None


@dataclass
class VerifyReport:
    read_back: dict[str, ParamValue]
    mismatches: list[str]
    sensor_present: bool
    method: str
    figures: dict[str, float] = field(default_factory=dict)
    missing: list[str] = field(default_factory=list)  # the sensors gone after the power cycle, by name
    store: str = ""  # where the calibration is kept and how that was proven, in words

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
    params_echoed: dict[str, ParamValue] = field(default_factory=dict)  # what the firmware answered the writes with
    params_read_back: dict[str, ParamValue] = field(default_factory=dict)
    persistence: dict[str, Any] = field(default_factory=dict)
    attachments: list[Attachment] = field(default_factory=list)
    run_id: int | None = None
    station_hash: str = ""  # the station file's content hash (which configuration judged the unit)
    reference_field_ut: float | None = None  # the field reference the unit was calibrated against
    field_check: dict[str, Any] | None = None  # the field source as the unit met it (model, value, last live check)
    store: str = ""  # where the record is kept (the sink's own words: a file, a server)
    aborted_phase: str | None = None  # the phase the operator stopped the unit in
    left_changed: dict[str, str] = field(default_factory=dict)  # DUT parameters not restored: name → state
    unverified_params: list[str] = field(default_factory=list)  # written, but the power cycle was not proven
    earlier_runs: int = 0  # runs of this serial already in the store (0: first test)
    earlier_passes: int = 0  # of those, how many passed (a re-test of a passed unit is said)
    review: list[dict[str, Any]] = field(default_factory=list)  # process-review flags (see core/quality/review)
    review_note: str = ""  # what the unit was compared with, or why it was not
    report: str = ""  # the unit's HTML report, when the station writes them (results.reports)
    report_error: str = ""  # why the report the station should have written is missing
    slot: str | None = None  # the fixture position on a station with slots
    slot_group: str | None = None  # the units that shared the motion with this one carry the same id
    # listeners that raised while the unit ran (which plugin, which hook, the message): warnings, the verdict
    # stands (core/plugins.py Plugins.notify)
    listener_faults: list[str] = field(default_factory=list)

    def sensor_titles(self) -> dict[str, str]:
        """Each calibrated magnetometer's section title by measurement prefix (``""`` the primary,
        ``mag2.`` …): "compass 2: HMC5883 (458786)". The console and the screen title their sections
        per compass with it, so both name a sensor the same way."""
        sensors = self.unit_info.get("magnetometers") if isinstance(self.unit_info, dict) else None
        titles = {}
        for i, m in enumerate(s for s in sensors or [] if isinstance(s, dict)):
            label = str(m.get("label") or "magnetometer")
            # no "compass 1: compass 1", nor "compass 1: (396809)" with nothing between
            named = "" if label == f"compass {i + 1}" else f": {label}"
            titles[str(m.get("prefix") or "") + "." if m.get("prefix") else ""] = \
                f"compass {i + 1}{named} ({m.get('device_id')})"
        return titles
