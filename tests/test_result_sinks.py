"""Several results stores per station: every record to each, the first one the station's own, a
plugin sink's options validated and handed to its factory as the model, the sink contract."""

from __future__ import annotations

import json
from pathlib import Path

from pydantic import BaseModel, ConfigDict

from magline.core.plugins import hookimpl, load_plugins
from magline.core.record import Outcome
from magline.core.results.contract import ResultSink
from magline.core.sequencer import Sequencer
from magline.core.station import load_station
from magline.core.station.checks import station_problems


class JsonLinesOptions(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True)
    path: str
    indent: int | None = None


class JsonLinesSink:
    """A plant system's feed: one JSON object per finished unit."""

    def __init__(self, path: Path, options: JsonLinesOptions) -> None:
        self.path, self.options, self.next_id = path, options, 1

    def begin(self, record):
        record.run_id, self.next_id = self.next_id, self.next_id + 1

    def save_attempt(self, record, attempt):
        if record.run_id is None:
            self.begin(record)

    def finish(self, record):
        with self.path.open("a", encoding="utf-8") as out:
            out.write(json.dumps({"run_id": record.run_id, "serial": record.serial,
                                  "verdict": str(record.verdict)}) + "\n")

    def history(self, serial):
        return []

    def close(self):
        pass


class Plugin:
    def __init__(self) -> None:
        self.given: list = []

    @hookimpl
    def magline_register_result_sinks(self, register):
        def factory(station, station_dir, entry, options):
            self.given.append((entry, options))
            return JsonLinesSink(station_dir / options.path, options)

        register("jsonl", factory, options=JsonLinesOptions)


TWO_STORES = {"results": [{"sink": "sqlite", "path": "units.sqlite"},
                          {"sink": "jsonl", "options": {"path": "units.jsonl"}}]}


def test_every_record_goes_to_each_store_and_the_first_is_the_stations_own(make_station, tmp_path):
    path = make_station()
    one_store = "results:\n  sink: sqlite\n  path: magline-demo-results.sqlite\n"
    two_stores = "results:\n- {sink: sqlite, path: units.sqlite}\n- sink: jsonl\n  options: {path: units.jsonl}\n"
    path.write_text(path.read_text(encoding="utf-8").replace(one_store, "") + two_stores, encoding="utf-8")
    plugin = Plugin()
    seq = Sequencer(load_station(path), load_plugins(extra=[plugin]), tmp_path, sleep=lambda s: None)
    try:
        records = [seq.run_unit(f"TWO-{i}") for i in range(2)]
        history = seq.sink.history("TWO-1")
    finally:
        seq.close()
    assert all(r.verdict is Outcome.PASS for r in records)
    (entry, options), = plugin.given
    assert isinstance(options, JsonLinesOptions) and options.path == "units.jsonl" and entry.sink == "jsonl"
    lines = [json.loads(x) for x in (tmp_path / "units.jsonl").read_text().splitlines()]
    assert [(x["serial"], x["verdict"], x["run_id"]) for x in lines] == [("TWO-0", "pass", 1), ("TWO-1", "pass", 2)]
    assert [r.run_id for r in records] == [1, 2]  # the station's own store's ids
    assert "units.sqlite run 2" in records[1].store and "also in jsonl" in records[1].store
    assert [h["serial"] for h in history] == ["TWO-1"] and history[0]["verdict"] == "pass"
    assert isinstance(seq.sink.main, ResultSink)


def test_a_store_that_cannot_take_the_record_makes_the_unit_an_error_naming_it(make_station, tmp_path):
    path = make_station(TWO_STORES)

    class Broken(JsonLinesSink):
        def finish(self, record):
            raise OSError("disk full")

    class BrokenPlugin:
        @hookimpl
        def magline_register_result_sinks(self, register):
            register("jsonl", lambda station, where, entry, options: Broken(where / "x.jsonl", options),
                     options=JsonLinesOptions)

    seq = Sequencer(load_station(path), load_plugins(extra=[BrokenPlugin()]), tmp_path, sleep=lambda s: None)
    try:
        record = seq.run_unit("BROKEN-1")
    finally:
        seq.close()
    assert record.verdict is Outcome.ERROR and "results store 'jsonl': finish failed: disk full" in record.cause


def test_store_options_and_names_are_checked_with_file_and_line(make_station):
    path = make_station({"results": [{"sink": "sqlite"}, {"sink": "jsonl", "options": {"pathh": "x"}},
                                     {"sink": "jsonll"}]})
    _, problems = station_problems(path.read_text(encoding="utf-8"), str(path), load_plugins(extra=[Plugin()]))
    text = "\n".join(problems)
    assert "results[1].options.pathh: unknown key (did you mean 'path'?)" in text
    assert "results[1].options.path: required key is missing" in text
    assert "results[2].sink: unknown results sink 'jsonll' (did you mean 'jsonl'?)" in text
    assert all(p.startswith(f"{path}:") and p.split(":")[1].isdigit() and p.split(":")[1] != "1" for p in problems)
    path = make_station({"results": {"sink": "sqlite", "pathh": "x.sqlite"}})  # the single mapping, as before
    _, problems = station_problems(path.read_text(encoding="utf-8"), str(path), load_plugins())
    assert len(problems) == 1 and "results.pathh: unknown key (did you mean 'path'?)" in problems[0]


def test_a_run_no_store_listens_to_is_an_error_before_the_unit_is_touched(make_station, tmp_path, monkeypatch):
    """Issue 44: the results stores hear the run through hooks (``magline.core.results.recorder``);
    with that listener switched off nothing would keep the unit, so it is refused in identify, an
    ERROR saying why — never a judgement nobody can trace, never a DUT connected for it."""
    monkeypatch.setenv("MAGLINE_DISABLE_PLUGINS", "results_store")
    seq = Sequencer(load_station(make_station()), load_plugins(), tmp_path, sleep=lambda s: None)
    try:
        record = seq.run_unit("NOBODY-1")
        history = seq.sink.history("NOBODY-1")
    finally:
        seq.close()
    assert record.verdict is Outcome.ERROR and record.phases[0].name == "identify"
    assert record.phases[0].outcome is Outcome.ERROR and record.phases[1].outcome is Outcome.SKIPPED
    assert "no results store began the run of NOBODY-1 (is the results_store plugin disabled?)" in record.cause
    assert record.store == "" and history == []


def test_two_stations_sharing_one_plugin_manager_keep_their_own_records(make_station, tmp_path):
    """The store listener writes into the stores the run carries (``run.results``), so two
    sequencers sharing one plugin manager — as a screen running two stations would — never write
    each other's units."""
    plugins = load_plugins()
    folders = [tmp_path / "a", tmp_path / "b"]
    records = []
    for folder, serial in zip(folders, ("A-1", "B-1"), strict=True):
        folder.mkdir()
        seq = Sequencer(load_station(make_station()), plugins, folder, sleep=lambda s: None)
        try:
            records.append((seq.run_unit(serial), seq.sink.history("A-1"), seq.sink.history("B-1")))
        finally:
            seq.close()
    (a, a_has_a, a_has_b), (b, b_has_a, b_has_b) = records
    assert a.verdict is b.verdict is Outcome.PASS
    assert [len(a_has_a), len(a_has_b), len(b_has_a), len(b_has_b)] == [1, 0, 0, 1]
