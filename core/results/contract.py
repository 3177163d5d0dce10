"""What a results store (a *sink*) must do: the contract every built-in and third-party sink meets.

Why a Protocol: the sequencer, ``magline history`` and the statistics call sinks only through
these methods, so a plugin author can check a sink against this file (and
``magline.testing``'s conformance suite) instead of reading the built-in stores.

Lifecycle of one unit: ``begin(record)`` (before the first attempt; sets ``record.run_id``) →
``save_attempt(record, attempt)`` for every acquisition attempt, the moment it ends, before any
fitting (raw data safe first) → ``finish(record)`` once, with the verdict and everything measured.
``close()`` once at the end of the batch.  A sink that cannot store raises
:class:`~magline.plugin.StationFault` naming itself: the unit is then an ERROR (a judgement
nobody can trace does not count).

Run ids: ``begin`` sets ``record.run_id`` to an int unique within the store and increasing with
each run, so ``magline show RUN_ID`` finds it; ``save_attempt`` and ``finish`` must work without
``begin`` too (they begin the run themselves).
"""

from __future__ import annotations

from typing import Any, Protocol, TypedDict, runtime_checkable

from magline.core.record import AttemptRecord, RunRecord


class HistoryAttempt(TypedDict):
    attempt: int
    samples: int
    coverage: float
    accepted: int | bool
    refused: str | None


class HistoryFailure(TypedDict):
    name: str
    value: float | None
    unit: str | None
    low: float | None
    high: float | None


class HistoryRun(TypedDict):
    """One run of a unit as ``history(serial)`` returns it (oldest first)."""

    id: int
    serial: str
    part: str
    station_id: str
    line: str
    operator: str
    started: str
    finished: str | None
    verdict: str
    cause: str | None
    limit_hash: str
    calibration: dict[str, Any] | None  # hard_iron_ut, soft_iron, field_ut, model, …
    aborted_phase: str | None
    attempts: list[HistoryAttempt]
    failed: list[HistoryFailure]  # the measurements that failed their limits


@runtime_checkable
class ResultSink(Protocol):
    def begin(self, record: RunRecord) -> None:
        """A unit starts: create its run and set ``record.run_id``."""

    def save_attempt(self, record: RunRecord, attempt: AttemptRecord) -> None:
        """Store one acquisition attempt with its raw readings (``attempt.raw``), at once."""

    def finish(self, record: RunRecord) -> None:
        """Store the finished record: verdict, cause, phases, measurements, parameters."""

    def history(self, serial: str) -> list[HistoryRun]:
        """Every run of ``serial`` in this store, oldest first (empty when none)."""

    def close(self) -> None:
        """Release the store (end of the batch)."""


# Optional, used when present: ``location(record) -> str`` (where the record is, in the operator's
# words), ``series(...)`` (statistics, process review), ``record_engine`` (a SQLAlchemy engine:
# reports), ``pending() -> int`` and ``forward()`` (store-and-forward), ``where`` (a description).
# ``claim_slot(holder) -> str | None`` / ``touch_slot(holder)`` / ``release_slot(holder)`` / ``slots_held()``
# (which station holds which slot across computers, see core/results/claims.py: the refusal sentence, or None).
OPTIONAL = ("location", "series", "record_engine", "pending", "forward", "where", "claim_slot", "touch_slot",
            "release_slot", "slots_held")
