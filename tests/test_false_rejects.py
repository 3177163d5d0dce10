"""Good units pass (issue 28): a statistical alarm is no verdict.  The fit's warm-up test fires on 10⁻³
of good tumbles; the readings it then sets aside are not readings judged bad, so they never count
toward ``rejected_fraction`` (whose limit fails units) but are kept as ``warm_up_fraction``."""

from __future__ import annotations

import numpy as np

from magline.core.plugins import hookimpl, load_plugins
from magline.core.record import Outcome
from magline.core.sequencer import Sequencer
from magline.core.station import load_station
from magline.testing import make_fit


def run_with_fit(make_station, rejected: dict[str, int]):
    used = np.ones(600, bool)
    used[: sum(rejected.values())] = False

    class SetAside:
        @hookimpl
        def magline_fit(self, run, samples, options):
            return make_fit(hard_iron_ut=(35.0, -22.0, 61.0), residuals_ut=np.full(int(used.sum()), 0.05),
                            used=used, rejected=dict(rejected), samples_total=600)

    path = make_station()
    seq = Sequencer(load_station(path), load_plugins(extra=[SetAside()]), path.parent, sleep=lambda s: None)
    try:
        return seq.run_unit("FR-1")
    finally:
        seq.close()


def measured(record, name):
    return next(m for m in record.measurements if getattr(m, "name", None) == name)


def test_a_warm_up_set_aside_is_not_a_rejection_and_the_unit_passes(make_station):
    record = run_with_fit(make_station, {"warm_up": 150})
    assert record.verdict is Outcome.PASS, record.cause
    assert measured(record, "rejected_fraction").value == 0.0
    assert measured(record, "warm_up_fraction").value == 0.25


def test_readings_judged_bad_still_count_against_the_limit(make_station):
    record = run_with_fit(make_station, {"spike": 40, "warm_up": 100})
    assert record.verdict is Outcome.FAIL
    assert measured(record, "rejected_fraction").value == 40 / 600
    assert record.cause.startswith("rejected_fraction")
