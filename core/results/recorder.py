"""The station's results stores as a listener of the run, as pytest's junitxml listens to a session:
the sequencer says a unit started, an attempt ended and the record is final
(``magline_unit_started``, ``magline_attempt_ended``, ``magline_record_unit``); this module writes
each into the run's own stores (``run.results``, opened by the sequencer from the station file).

Why the run's stores and not a store registered at start: slots of one station share one plugin
manager, and each unit's run carries the stores it belongs to, so no slot's record can land in
another's.  Why answers: the sequencer requires a store to answer each call — a unit no store heard
of (this plugin disabled, no store opened) is an ERROR, never a judgement run unrecorded.  A store's
:class:`~magline.core.faults.StationFault` propagates to the phase that called it (ERROR).  Why
``tryfirst``: the stores write before any other listener hears the call, so a screen or a plant feed
listening to the same hook sees the run id and the record already kept.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from magline.core.plugins import hookimpl
from magline.core.results.contract import SaysWhere

if TYPE_CHECKING:
    from magline.core.record import AttemptRecord, RunRecord
    from magline.core.sequencer.context import RunContext


def _store_name(run: RunContext) -> str:
    return run.station.main_results.sink


@hookimpl(tryfirst=True)
def magline_unit_started(run: RunContext) -> str | None:
    if run.results is None:
        return None
    run.results.begin(run.record)
    return _store_name(run)


@hookimpl(tryfirst=True)
def magline_attempt_ended(run: RunContext, attempt: AttemptRecord) -> str | None:
    if run.results is None:
        return None
    run.results.save_attempt(run.record, attempt)
    return _store_name(run)


@hookimpl(tryfirst=True)
def magline_record_unit(run: RunContext, record: RunRecord) -> str | None:
    if run.results is None:
        return None
    run.results.finish(record)
    return run.results.location(record) if isinstance(run.results, SaysWhere) else _store_name(run)
