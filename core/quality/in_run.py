"""The in-run process review as a listener of the run (``magline_unit_judged``): a unit inside its
limits compared with the recent passing units of its part on its line (:mod:`.review` does the
arithmetic).  Why a listener and not a step of the sequencer: the review is an output of the process
watch, like a report; the sequencer runs the procedure and says when a unit is judged, and whoever
watches the process listens (a line can disable it as any plugin: ``review.enabled: false`` in the
station file, or ``MAGLINE_DISABLE_PLUGINS=process_review``).  A flag marks the measurement
``review`` and the record; it never fails the unit, and a store that cannot answer only leaves a note.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

from magline.core.faults import StationFault
from magline.core.measurements import Numeric, Verdict
from magline.core.plugins import hookimpl
from magline.core.record import Outcome
from magline.core.results.contract import KeepsSeries

if TYPE_CHECKING:
    from magline.core.sequencer.context import RunContext


@hookimpl
def magline_unit_judged(run: RunContext, measurements: list[Numeric]) -> None:
    settings = run.station.review
    if not settings.enabled:
        run.record.review_note = "process review off in the station file"
        return
    if not isinstance(run.results, KeepsSeries):
        run.record.review_note = (f"no process review: the results sink {run.station.main_results.sink!r} "
                                  "keeps no history")
        run.log(run.record.review_note)
        return
    from magline.core.quality.review import review  # on use: its NumPy costs every command's start
    from magline.core.results.reading import RunFilter  # on use: the store's SQLAlchemy costs every command's start

    numeric = [m for m in measurements if m.name not in settings.exclude]
    started = time.monotonic()
    try:
        past = run.results.series(RunFilter(part=run.record.part, line=run.record.line, verdict=str(Outcome.PASS)),
                         last=settings.window, names=[m.name for m in numeric], with_limits=False)
    except StationFault as exc:
        run.record.review_note = f"no process review: {exc}"
        run.log(run.record.review_note)
        return
    result = review(numeric, past.values, units=len(past), min_units=settings.min_units,
                    sigma=settings.sigma, exclude=settings.exclude,
                    what=f"{run.record.part} units on line {run.record.line}")
    run.record.review_note = result.note
    run.record.review = [f.to_dict() for f in result.flags]
    flagged = {f.name for f in result.flags}
    for m in numeric:
        if m.name in flagged:
            m.verdict = Verdict.REVIEW
    run.log(f"process review ({(time.monotonic() - started) * 1e3:.0f} ms): {result.note}")
    for f in result.flags:
        run.log(f"REVIEW: {f.reason}")
