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

from typing import TYPE_CHECKING, Any, Protocol, TypedDict, runtime_checkable

if TYPE_CHECKING:
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


# ---------------------------------------------------------------------------------------------- optional
# What some stores can do and others cannot: a sink has a capability by having its member; the core
# asks ``isinstance(sink, Capability)`` (a fan-out of several stores answers for the first, the
# station's own).


@runtime_checkable
class SaysWhere(Protocol):
    """Where a stored record is, in the operator's words (a file, a server, an outbox)."""

    def location(self, record: RunRecord) -> str: ...


@runtime_checkable
class KeepsSeries(Protocol):
    """The latest runs matching a filter with their numeric measurements as arrays: statistics, control
    charts and the in-run process review read it (``magline.core.results.series.RunSeries``)."""

    def series(self, where: Any, last: int | None = None, names: Any = None, with_attempts: bool = False,
               with_limits: bool = True, first: int | None = None) -> Any: ...


@runtime_checkable
class HoldsRecordsInSql(Protocol):
    """A SQLAlchemy engine over the tables the record just written is in (a forwarding store: its
    outbox): the unit report written at the end of a run reads it."""

    record_engine: Any


@runtime_checkable
class ReadsInSql(Protocol):
    """A SQLAlchemy engine over the store's tables to read (a forwarding store: the server): ``show``,
    ``export`` and ``report`` read it."""

    engine: Any


@runtime_checkable
class ClaimsSlots(Protocol):
    """Which station holds which slot across computers (``core/results/claims.py``): ``claim_slot``
    returns the sentence refusing the claim, or None when it is the holder's."""

    def claim_slot(self, holder: dict) -> str | None: ...

    def touch_slot(self, holder: dict) -> None: ...

    def release_slot(self, holder: dict) -> None: ...

    def slots_held(self) -> list[dict[str, Any]]: ...


@runtime_checkable
class ForwardsQueued(Protocol):
    """Store and forward: records queued while the server was away, and sending them on."""

    def pending(self) -> int: ...

    def forward(self) -> tuple[int, int]: ...
