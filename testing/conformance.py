"""Conformance suites: the contracts of magline's plugin kinds, checked against an author's own.

``check_result_sink(open_sink, folder)`` drives a sink exactly as the sequencer does and fails
with the broken rule of :mod:`magline.core.results.contract` (run ids, the ``history`` shape,
raw data stored before the verdict, storage that outlives the process's handle).  magline's own
stores run it in magline's CI.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from magline.core.fit.samples_csv import RawSamples
from magline.core.record import AttemptRecord, Outcome, RunRecord
from magline.core.results.contract import HistoryAttempt, HistoryRun, ResultSink
from magline.testing.builders import make_record


def _attempt(n: int, accepted: bool) -> AttemptRecord:
    rng = np.random.default_rng(n)
    raw = RawSamples(mag_ut=rng.normal(size=(50, 3)) * 40.0, t_ms=np.arange(50) * 20.0)
    return AttemptRecord(attempt=n, samples=50, coverage=0.9, target=0.6, raw=raw, accepted=accepted,
                         refused=None if accepted else "coverage 20 % below the target 60 %")


def _unit(sink: Any, serial: str, verdict: Outcome, begin: bool = True) -> RunRecord:
    record = make_record(serial=serial, part="CONFORMANCE-1", verdict=Outcome.ERROR)  # the sequencer's start value
    if begin:
        sink.begin(record)
        assert isinstance(record.run_id, int), f"begin() must set record.run_id to an int (got {record.run_id!r})"
    for n, accepted in ((1, False), (2, True)):
        attempt = _attempt(n, accepted)
        record.attempts.append(attempt)
        sink.save_attempt(record, attempt)
        assert isinstance(record.run_id, int), "save_attempt() without begin() must begin the run (set run_id)"
    record.verdict, record.finished = verdict, "2026-11-24T12:00:00+00:00"
    record.cause = "" if verdict is Outcome.PASS else "hard_iron_norm_ut = 400 µT outside [—, 300]"
    sink.finish(record)
    return record


def _check_shape(run: dict, serial: str) -> None:
    for key in HistoryRun.__annotations__:
        assert key in run, f"history() rows need the key {key!r} (see magline.core.results.contract.HistoryRun)"
    assert run["serial"] == serial and isinstance(run["id"], int) and isinstance(run["verdict"], str)
    assert isinstance(run["attempts"], list) and isinstance(run["failed"], list)
    for attempt in run["attempts"]:
        missing = [k for k in HistoryAttempt.__annotations__ if k not in attempt]
        assert not missing, f"history() attempts need the keys {missing}"


def check_result_sink(open_sink: Callable[[Path], Any], folder: str | Path) -> None:
    """Run the results-sink contract: ``open_sink(folder)`` opens your sink on a store in ``folder``
    (called twice: the second time it must find what the first stored)."""
    folder = Path(folder)
    sink = open_sink(folder)
    assert isinstance(sink, ResultSink), ("the sink lacks part of the contract: begin, save_attempt, finish, "
                                          "history, close (magline.core.results.contract.ResultSink)")
    try:
        first = _unit(sink, "CONF-1", Outcome.PASS)
        second = _unit(sink, "CONF-2", Outcome.FAIL)
        third = _unit(sink, "CONF-1", Outcome.PASS, begin=False)
        ids = [first.run_id, second.run_id, third.run_id]
        assert ids == sorted(ids) and len(set(ids)) == 3, f"run ids must be unique and increasing (got {ids})"
        assert sink.history("NOT-THERE") == [], "history() of an unknown serial is an empty list"
    finally:
        sink.close()
    sink = open_sink(folder)  # a new handle on the same store: the records outlive the first one
    try:
        runs = sink.history("CONF-1")
        assert [r["id"] for r in runs] == [first.run_id, third.run_id], (
            f"history('CONF-1') must list its two runs oldest first, from a new handle on the store (got {runs})")
        for run in runs:
            _check_shape(run, "CONF-1")
        assert [len(r["attempts"]) for r in runs] == [2, 2], "every saved attempt is in the history"
        failed = sink.history("CONF-2")
        assert failed and failed[0]["verdict"] == "fail" and failed[0]["cause"], "the verdict and cause are stored"
    finally:
        sink.close()
