"""Listener hooks see a unit's run in order: phases, prompts, progress, the final record."""

from __future__ import annotations

from magline.core.plugins import hookimpl, load_plugins
from magline.core.sequencer import PHASES, Sequencer
from magline.core.sequencer.sequencer import OPTIONAL_PHASES
from magline.core.station import load_station


class Recorder:
    def __init__(self):
        self.events = []

    @hookimpl
    def magline_phase_started(self, run, phase):
        self.events.append(("start", phase))

    @hookimpl
    def magline_phase_finished(self, run, phase, result):
        self.events.append(("end", phase, str(result.outcome)))

    @hookimpl
    def magline_operator_prompt(self, run, message):
        self.events.append(("prompt", message))

    @hookimpl
    def magline_acquisition_progress(self, run, attempt, samples, coverage, target):
        self.events.append(("progress", attempt, samples, coverage))

    @hookimpl
    def magline_unit_finished(self, run, record):
        self.events.append(("finished", str(record.verdict)))


class ExtraSink:
    @hookimpl
    def magline_register_result_sinks(self, register):
        register("memory", lambda station, where, entry, options: self)

    @hookimpl
    def magline_register_field_sources(self, register):
        register("constant50", lambda station, options: type("F", (), {"reference_field_ut": lambda self: 48.0})())

    def __init__(self):
        self.finished = []
        self.attempts = []

    def begin(self, record):
        pass

    def save_attempt(self, record, attempt):
        self.attempts.append(attempt.attempt)

    def finish(self, record):
        self.finished.append(record.serial)

    def history(self, serial):
        return []


def test_listeners_and_registries(make_station, tmp_path):
    rec, sink = Recorder(), ExtraSink()
    path = make_station({"results": {"sink": "memory"}, "field_source": {"type": "constant50", "options": {}}})
    plugins = load_plugins(extra=[rec, sink])
    Sequencer(load_station(path), plugins, tmp_path, sleep=lambda s: None).run_unit("L-1")
    starts = [e[1] for e in rec.events if e[0] == "start"]
    assert tuple(starts) == tuple(p for p in PHASES if p not in OPTIONAL_PHASES)  # the sweep: products that ask
    assert rec.events[-1] == ("finished", "pass")
    prompts = [e[1] for e in rec.events if e[0] == "prompt"]
    assert prompts[0].startswith("Tumble") and prompts[1].startswith("Coverage too low")
    progress = [e for e in rec.events if e[0] == "progress"]
    assert {p[1] for p in progress} == {1, 2} and progress[-1][2] >= 100  # at least min_samples
    assert sink.attempts == [1, 2] and sink.finished == ["L-1"]
