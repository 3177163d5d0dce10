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


class BrokenFeed:
    """A plant feed whose file is not writable: its listeners raise."""

    @hookimpl
    def magline_phase_finished(self, run, phase, result):
        if phase == "fit":
            raise OSError("phase log full")

    @hookimpl
    def magline_unit_finished(self, run, record):
        raise PermissionError(f"/plant/feed.jsonl: not writable (unit {record.serial})")


def test_a_listener_that_raises_is_a_warning_on_the_record_and_the_verdict_and_the_batch_go_on(make_station):
    """Issue 66: a third party's listener failing after the verdict printed a traceback, exited 1 and stopped
    a --loop batch.  Now each listener is called on its own: the others still hear, the failure is said with
    its plugin and hook, and the next unit runs."""
    recorder = Recorder()
    path = make_station()
    seq = Sequencer(load_station(path), load_plugins(extra=[BrokenFeed(), recorder]), path.parent,
                    sleep=lambda s: None)
    try:
        first, second = seq.run_unit("FEED-1"), seq.run_unit("FEED-2")
    finally:
        seq.close()
    assert first.verdict.value == "pass" and second.verdict.value == "pass"
    assert any("BrokenFeed" in f and "magline_unit_finished" in f and "PermissionError" in f and "FEED-1" in f
               for f in first.listener_faults), first.listener_faults
    assert any("magline_phase_finished: OSError: phase log full" in f for f in first.listener_faults)
    assert [e for e in recorder.events if e[0] == "finished"] == [("finished", "pass"), ("finished", "pass")]


def test_the_command_exits_as_the_verdict_says_when_a_listener_fails(make_station, monkeypatch, capsys):
    from magline.core import cli
    from magline.core.cli import main

    real = cli.load_plugins
    monkeypatch.setattr(cli, "load_plugins",
                        lambda extra=None, **how: real(extra=[*(extra or []), BrokenFeed()], **how))
    path = make_station()
    assert main(["run", str(path), "--serial", "FEED-CLI"]) == 0
    err = capsys.readouterr().err
    assert "warning: a listener failed on FEED-CLI: plugin" in err and "Traceback" not in err
