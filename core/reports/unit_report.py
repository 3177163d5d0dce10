"""The unit's HTML report as a listener of the run (``magline_unit_finished``), as pytest's junitxml
listens to a test session: the sequencer stores the record and says the unit is finished; this writes
the page from the stored record when the station file asks for reports (``results.reports``).

A report that cannot be written is said in the record (``report_error``), never a reason to change
the unit's verdict: the record is kept.  ``tryfirst``: the console and the screen, listening to the
same call, show the report's path.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from magline.core.faults import StationFault
from magline.core.plugins import hookimpl
from magline.core.results.contract import HoldsRecordsInSql

if TYPE_CHECKING:
    from magline.core.record import RunRecord
    from magline.core.sequencer.context import RunContext


@hookimpl(tryfirst=True)
def magline_unit_finished(run: RunContext, record: RunRecord) -> None:
    folder_name = run.station.main_results.reports
    if folder_name is None or not record.store:  # no reports asked, or nothing stored to report
        return
    from magline.core.reports.commands import write_report  # plotly and the page: only when a report is due
    from magline.core.results.reading import RunNotFound

    try:
        if not isinstance(run.results, HoldsRecordsInSql):
            raise StationFault(f"the results sink {run.station.main_results.sink!r} is not a SQL store")
        folder = run.station_dir / folder_name
        record.report = str(write_report(run.results.record_engine, str(record.run_id), None, folder))
    except (StationFault, OSError, RunNotFound) as exc:
        record.report_error = f"report not written: {exc}"
