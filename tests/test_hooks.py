"""A test per hook, named for it (datasette's ``test_plugin_hooks_have_tests``): each hook of
``core/hookspecs.py`` implemented by a plugin object the way a third-party plugin would, on the
embedded demo station (the in-process mock unit), and what the plugin received or changed checked.

The listener hooks share one unit's run (``heard``); the hooks that change the run get a unit each.
``test_every_hook_has_a_test_named_for_it_and_its_signature_in_the_reference`` keeps it so.
"""

from __future__ import annotations

import csv
import inspect
import threading
from pathlib import Path

import pytest
from conftest import REPO, deep_update, demo_config
from pydantic import BaseModel, ConfigDict

from magline.core import hookspecs
from magline.core.measurements import Numeric
from magline.core.plugins import hookimpl, load_plugins
from magline.core.record import Outcome, RunRecord
from magline.core.sequencer import Sequencer
from magline.core.station import load_station
from magline.testing.reference import _signature

HOOKS = sorted(name for name, fn in inspect.getmembers(hookspecs, inspect.isfunction) if name.startswith("magline_"))


def write_station(folder: Path, changes: dict | None = None) -> Path:
    import yaml

    cfg = deep_update(demo_config(), {"products": {"MOCK-100": {"options": {"realtime": False, "seed": 7}}},
                                      "acquisition": {"retry_delay_s": 0.0, "stop": "samples"},
                                      "results": {"path": str(folder / "results.sqlite")}})
    path = folder / "station.yaml"
    path.write_text(yaml.safe_dump(deep_update(cfg, changes or {}), sort_keys=False), encoding="utf-8")
    return path


def run_with(folder: Path, *plugins: object, changes: dict | None = None, serial: str = "HOOK-1") -> RunRecord:
    path = write_station(folder, changes)
    seq = Sequencer(load_station(path), load_plugins(extra=list(plugins)), folder, sleep=lambda s: None)
    try:
        return seq.run_unit(serial)
    finally:
        seq.close()


class Listener:
    """Every listener hook: what each call received, in order."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, dict]] = []
        self.tick = threading.Event()

    def of(self, hook: str) -> list[dict]:
        return [kw for name, kw in self.calls if name == hook]

    @hookimpl
    def magline_phase_started(self, run, phase):
        self.calls.append(("magline_phase_started", {"phase": phase}))
        if phase == "connect":  # a wait of the station's, as the power cycle's: a countdown, then its end
            with run.waiting("the hook test's wait", 5.0, tick_s=0.02):
                self.tick.wait(10.0)

    @hookimpl
    def magline_phase_finished(self, run, phase, result):
        self.calls.append(("magline_phase_finished", {"phase": phase, "outcome": result.outcome}))

    @hookimpl
    def magline_acquisition_progress(self, run, attempt, samples, coverage, target, bins, n_bins):
        self.calls.append(("magline_acquisition_progress", {"attempt": attempt, "samples": samples,
                                                            "coverage": coverage, "target": target}))

    @hookimpl
    def magline_acquisition_stopped(self, run, attempt, reason, after_s, readings, predicted):
        self.calls.append(("magline_acquisition_stopped", {"attempt": attempt, "reason": reason,
                                                           "readings": readings}))

    @hookimpl
    def magline_waiting(self, run, what, elapsed_s, limit_s):
        self.calls.append(("magline_waiting", {"what": what, "elapsed_s": elapsed_s, "limit_s": limit_s}))
        if what == "the hook test's wait":
            self.tick.set()

    @hookimpl
    def magline_wait_ended(self, run, what, waited_s):
        self.calls.append(("magline_wait_ended", {"what": what, "waited_s": waited_s}))

    @hookimpl
    def magline_motion_started(self, round, slots, motion):
        self.calls.append(("magline_motion_started", {"round": round, "slots": slots, "motion": motion}))

    @hookimpl
    def magline_motion_stopped(self, round, slots, motion):
        self.calls.append(("magline_motion_stopped", {"round": round, "slots": slots, "motion": motion}))

    @hookimpl
    def magline_operator_prompt(self, run, message):
        self.calls.append(("magline_operator_prompt", {"message": message}))

    @hookimpl
    def magline_unit_started(self, run):
        self.calls.append(("magline_unit_started", {"run_id": run.record.run_id, "phase": run.record.phases[-1].name}))

    @hookimpl
    def magline_attempt_ended(self, run, attempt):
        self.calls.append(("magline_attempt_ended", {"attempt": attempt, "fitted": run.fit is not None}))

    @hookimpl
    def magline_record_unit(self, run, record):
        self.calls.append(("magline_record_unit", {"verdict": record.verdict, "finished": record.finished}))
        return "the hook test's ledger"

    @hookimpl
    def magline_unit_judged(self, run, measurements):
        self.calls.append(("magline_unit_judged", {"names": [m.name for m in measurements]}))

    @hookimpl
    def magline_unit_finished(self, run, record):
        self.calls.append(("magline_unit_finished", {"record": record}))


@pytest.fixture(scope="module")
def heard(tmp_path_factory) -> tuple[Listener, RunRecord]:
    listener = Listener()
    record = run_with(tmp_path_factory.mktemp("heard"), listener)
    assert record.verdict is Outcome.PASS, record.cause
    return listener, record


# ----------------------------------------------------------------------------------- registration
class HookCurrentOptions(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True)
    amps: float


class Registers:
    @hookimpl
    def magline_register_dut_backends(self, register):
        register("hook-dut", lambda product, options: None)

    @hookimpl
    def magline_register_field_sources(self, register):
        register("hook-field", lambda station, options: None)

    @hookimpl
    def magline_register_result_sinks(self, register):
        register("hook-sink", lambda station, folder, entry, options: None)

    @hookimpl
    def magline_register_power_controls(self, register):
        register("hook-power", lambda config, folder, options: None)

    @hookimpl
    def magline_register_motions(self, register):
        register("hook-motion", lambda station, folder, options: None)

    @hookimpl
    def magline_register_current_sources(self, register):
        register("hook-current", lambda config, folder, options: ("made", config.type, folder, options),
                 options=HookCurrentOptions)


@pytest.fixture(scope="module")
def registered():
    return load_plugins(extra=[Registers()])


def test_magline_register_dut_backends(registered):
    assert "hook-dut" in registered.dut_backends and "mock" in registered.dut_backends


def test_magline_register_field_sources(registered):
    assert "hook-field" in registered.field_sources and "fixed" in registered.field_sources


def test_magline_register_result_sinks(registered):
    assert "hook-sink" in registered.result_sinks and "sqlite" in registered.result_sinks


def test_magline_register_power_controls(registered):
    assert "hook-power" in registered.power_controls and "link-reboot" in registered.power_controls


def test_magline_register_motions(registered):
    assert "hook-motion" in registered.motions and "operator" in registered.motions


def test_magline_register_current_sources(registered, tmp_path):
    """The station's ``current_source`` is made by the registered factory with its options validated
    against the declared model; a wrong option is refused naming the key."""
    from magline.core.interference.source import open_current_source
    from magline.core.station.schema import Station

    assert "hook-current" in registered.current_sources and "electronic-load" in registered.current_sources

    def station(options: dict) -> Station:
        return Station.model_validate({"station": {"id": "s", "line": "L", "location": {"latitude_deg": 0.0,
                                                                                      "longitude_deg": 0.0}},
                                       "products": {"P": {"backend": "mock"}},
                                       "current_source": {"type": "hook-current", "options": options}})

    made = open_current_source(station({"amps": 3.0}), tmp_path, registered)
    assert made[:3] == ("made", "hook-current", tmp_path) and made[3].amps == 3.0
    with pytest.raises(Exception, match=r"current_source\.options"):
        open_current_source(station({"amps": "lots"}), tmp_path, registered)


def test_magline_add_commands(monkeypatch, capsys):
    import magline.core.cli as cli

    class Command:
        @hookimpl
        def magline_add_commands(self, subparsers):
            parser = subparsers.add_parser("hook-hello", help="say hello")
            parser.add_argument("name")
            parser.set_defaults(handler=lambda args: print(f"hello {args.name}") or 3)

    real = cli.load_plugins
    monkeypatch.setattr(cli, "load_plugins", lambda **how: real(extra=[Command()], **how))
    assert cli.main(["hook-hello", "line"]) == 3
    assert capsys.readouterr().out == "hello line\n"


# ----------------------------------------------------------------------------------- the phases
def test_magline_acquire(tmp_path):
    """A plugin's acquire is asked first (``firstresult``); returning None leaves it to the core's."""
    asked: list[int] = []

    class Watch:
        @hookimpl
        def magline_acquire(self, run, attempt):
            asked.append(attempt)

    record = run_with(tmp_path, Watch())
    assert record.verdict is Outcome.PASS and asked == [a.attempt for a in record.attempts]


def test_magline_fit(tmp_path):
    """A plugin's fit replaces the core's: its result is what the unit is calibrated with."""
    from magline.core.fit import fit_calibration

    fitted: list[int] = []

    class Fit:
        @hookimpl
        def magline_fit(self, run, samples, options):
            fitted.append(len(samples.mag_ut))
            return fit_calibration(samples.mag_ut, options, t_ms=samples.t_ms, temp_c=samples.temp_c)

    record = run_with(tmp_path, Fit())
    assert record.verdict is Outcome.PASS, record.cause
    assert fitted == [len(record.attempts[-1].raw.mag_ut)]


def test_magline_validate(tmp_path):
    """What a plugin measures on each sensor's fit is recorded beside the core's, under the sensor's
    prefix, judged against the station's limits (a name the catalogue does not know has none: info)."""
    given = []

    class Extra:
        @hookimpl
        def magline_validate(self, run, fit):
            given.append(fit.hard_iron_ut.tolist())
            return [Numeric(name="hook_extra_ut", value=5.0, unit="µT")]

    record = run_with(tmp_path, Extra())
    assert record.verdict is Outcome.PASS, record.cause
    extra = next(m for m in record.measurements if m.name == "hook_extra_ut")
    assert extra.value == 5.0 and str(extra.verdict) == "info" and given == [record.calibration["hard_iron_ut"]]


def test_magline_validate_unit(tmp_path):
    seen: list[list[int]] = []

    class Unit:
        @hookimpl
        def magline_validate_unit(self, run, fits):
            seen.append(list(fits))
            return [Numeric(name="hook_unit_figure", value=1.0, unit="")]

    record = run_with(tmp_path, Unit())
    assert record.verdict is Outcome.PASS, record.cause
    assert seen == [[m["device_id"] for m in record.unit_info["magnetometers"]]]
    assert next(m for m in record.measurements if m.name == "hook_unit_figure").value == 1.0


def test_magline_register_measurements(tmp_path, capsys):
    """A plugin's own measurement is a measurement: a station file limits it (refused, saying how to declare
    it, where no loaded plugin does), the unit is judged on it in its declared unit, the limit is in the
    limit set's hash, ``export`` has its column and ``spc --measurement`` takes its name."""
    from magline.core.cli import main
    from magline.core.quality.commands import unknown_measurements
    from magline.core.station import StationError

    class Declares:
        @hookimpl
        def magline_register_measurements(self, register):
            register("hook_board_temp_c", unit="°C", meaning="the board's temperature", possible=(-60.0, 150.0))

        @hookimpl
        def magline_validate_unit(self, run, fits):
            return [run.measured("hook_board_temp_c", 72.0)]

    plugins = load_plugins(extra=[Declares()])
    path = write_station(tmp_path, {"limits": {"hook_board_temp_c": {"le": 60.0}}})
    with pytest.raises(StationError, match="magline_register_measurements hook"):
        load_station(path)  # read without the plugin: an unknown name, and how to make it known
    station = load_station(path, plugins)
    assert station.limit_hash("MOCK-100") != load_station(
        write_station(tmp_path, {"limits": {"hook_board_temp_c": {"le": 80.0}}}), plugins).limit_hash("MOCK-100")
    seq = Sequencer(station, plugins, tmp_path, sleep=lambda s: None)
    try:
        record = seq.run_unit("HOOK-T")
    finally:
        seq.close()
    temp = next(m for m in record.measurements if m.name == "hook_board_temp_c")
    assert (temp.value, temp.unit, temp.high, str(temp.verdict)) == (72.0, "°C", 60.0, "fail")
    assert record.verdict is Outcome.FAIL and "hook_board_temp_c" in record.cause
    assert record.params_written == {}  # never written to a unit that failed
    from magline.core.measurements import verdicts
    from magline.core.operator_ui.verdict_words import verdict_items

    failed, = [item for item in verdict_items(record, verdicts(record.measurements))
               if item["name"] == "hook_board_temp_c"]
    assert (failed["label"], failed["value"]) == ("The board's temperature", "72 °C")  # the operator's words
    capsys.readouterr()
    write_station(tmp_path)  # the same store, read by the command (which loads only the installed plugins)
    assert main(["export", "--station", str(path)]) == 0
    header, row = list(csv.reader(capsys.readouterr().out.splitlines()))[:2]
    assert float(row[header.index("hook_board_temp_c")]) == 72.0
    assert main(["report", str(record.run_id), "--station", str(path), "-o", str(tmp_path / "unit.html")]) == 0
    assert "hook_board_temp_c" in (tmp_path / "unit.html").read_text(encoding="utf-8")
    assert unknown_measurements(["hook_board_temp_c"], plugins.measurements) is None
    assert "magline measures" in unknown_measurements(["hook_board_temp_c"])


def test_magline_connection_problem(tmp_path):
    """A backend's plugin judges the connections of its own products (and slots) when the station is read: its
    sentence is said with file, line and key; the other backends' products are not asked of it."""
    from magline.testing import check_station

    asked: list[tuple[str, str]] = []

    class Judge:
        @hookimpl
        def magline_connection_problem(self, backend, connection):
            asked.append((backend, connection))
            return "the bench has no port 9" if backend == "mock" and connection.endswith(":9") else None

    plugins = load_plugins(extra=[Judge()])
    good = write_station(tmp_path, {"products": {"MOCK-100": {"connection": "bench:1"}}})
    assert check_station(good, plugins) == [] and asked == [("mock", "bench:1")]
    bad = write_station(tmp_path, {"products": {"MOCK-100": {"connection": "bench:9"}}})
    (problem,) = check_station(bad, plugins)
    assert (problem.key, problem.message) == ("products.MOCK-100.connection", "the bench has no port 9")
    assert bad.read_text(encoding="utf-8").splitlines()[problem.line - 1].strip().startswith("connection:")

    class Broken:
        @hookimpl
        def magline_connection_problem(self, backend, connection):
            raise KeyError(backend)

    (problem,) = check_station(good, load_plugins(extra=[Broken()]))
    assert problem.key == "products.MOCK-100.connection"
    assert problem.message == "plugin 'Broken' could not judge it: KeyError: 'mock'"


def test_magline_register_plugin_options(tmp_path):
    """A listener configured in the station file: ``plugins.<section>`` validated by the plugin's model when
    the station is read (file, key and line), handed to the plugin by ``run.plugin_options``; a section no
    plugin registered is refused, naming the loaded ones."""
    from magline.testing import check_station

    class FeedOptions(BaseModel):
        model_config = ConfigDict(extra="forbid", strict=True)
        path: str
        parts: list[str] | None = None

    heard: list[tuple[str, object]] = []

    class Feed:
        @hookimpl
        def magline_register_plugin_options(self, register):
            register("hook-feed", FeedOptions)

        @hookimpl
        def magline_unit_finished(self, run, record):
            heard.append((record.part, run.plugin_options("hook-feed")))

    plugins = load_plugins(extra=[Feed()])
    path = write_station(tmp_path, {"plugins": {"hook-feed": {"path": "plant/feed.jsonl", "parts": ["MOCK-100"]}}})
    assert check_station(path, plugins) == []
    seq = Sequencer(load_station(path, plugins), plugins, tmp_path, sleep=lambda s: None)
    try:
        seq.run_unit("HOOK-F")
    finally:
        seq.close()
    (part, options), = heard
    assert part == "MOCK-100" and isinstance(options, FeedOptions) and options.path == "plant/feed.jsonl"
    wrong = write_station(tmp_path, {"plugins": {"hook-feed": {"path": 5}, "hook-fed": {}}})
    problems = [(p.key, p.message) for p in check_station(wrong, plugins)]
    assert ("plugins.hook-feed.path", "Input should be a valid string (got int 5)") in problems
    assert [k for k, m in problems if m.startswith("unknown plugins: section 'hook-fed' (did you mean 'hook-feed'")] \
        == ["plugins.hook-fed"]


@pytest.mark.parametrize(("name", "why"), [("coverage", "is magline's own"), ("Board Temp", "lower-case letters"),
                                           ("hook_twice_c", "is declared by plugin")])
def test_a_measurement_a_plugin_cannot_declare_is_a_plugin_error_naming_it(name, why):
    from magline.core.plugins import PluginError

    class Declares:
        @hookimpl
        def magline_register_measurements(self, register):
            register(name, unit="°C")
            if name == "hook_twice_c":
                register(name, unit="°C")

    with pytest.raises(PluginError, match=why):
        load_plugins(extra=[Declares()])


def test_magline_persist(tmp_path):
    """The persist phase is asked with the primary's fit; None leaves it to the core's."""
    given = []

    class Persist:
        @hookimpl
        def magline_persist(self, run, fit):
            given.append(fit.hard_iron_ut.tolist())

    record = run_with(tmp_path, Persist())
    assert record.verdict is Outcome.PASS and given == [record.calibration["hard_iron_ut"]]


def test_magline_verify_persistence(tmp_path):
    """A plugin's verify replaces the core's: a mismatch it reports fails the unit at verify."""
    from magline.core.record import VerifyReport

    class Verify:
        @hookimpl
        def magline_verify_persistence(self, run, persisted):
            return VerifyReport(read_back=dict(persisted.written), mismatches=["hook says no"], sensor_present=True,
                                method="hook", figures={}, missing=[])

    record = run_with(tmp_path, Verify())
    assert record.verdict is Outcome.FAIL and "hook says no" in record.cause
    assert [p.name for p in record.phases if p.outcome is Outcome.FAIL] == ["verify"]


# ----------------------------------------------------------------------------------- listeners
def test_magline_phase_started(heard):
    listener, record = heard
    assert [c["phase"] for c in listener.of("magline_phase_started")] == [p.name for p in record.phases]


def test_magline_phase_finished(heard):
    listener, record = heard
    finished = listener.of("magline_phase_finished")
    assert [(c["phase"], c["outcome"]) for c in finished] == [(p.name, p.outcome) for p in record.phases]


def test_magline_acquisition_progress(heard):
    listener, record = heard
    progress = listener.of("magline_acquisition_progress")
    assert progress and {c["attempt"] for c in progress} == {a.attempt for a in record.attempts}
    for attempt in record.attempts:  # coverage only grows as readings arrive, up to the attempt's own
        shown = [c["coverage"] for c in progress if c["attempt"] == attempt.attempt]
        assert shown == sorted(shown) and shown[0] >= 0.0 and shown[-1] <= attempt.coverage + 1e-12


def test_magline_acquisition_stopped(heard):
    listener, record = heard
    stopped = listener.of("magline_acquisition_stopped")
    assert [(c["attempt"], c["reason"]) for c in stopped] == [(a.attempt, a.stopped) for a in record.attempts]


def test_magline_waiting(heard):
    listener, _ = heard
    ticks = [c for c in listener.of("magline_waiting") if c["what"] == "the hook test's wait"]
    assert ticks and ticks[0]["limit_s"] == 5.0 and all(c["elapsed_s"] >= 0.0 for c in ticks)


def test_magline_wait_ended(heard):
    listener, _ = heard
    ended = [c for c in listener.of("magline_wait_ended") if c["what"] == "the hook test's wait"]
    assert len(ended) == 1  # once, and no tick after it
    names = [(n, kw.get("what")) for n, kw in listener.calls]
    last_tick = max(i for i, (n, w) in enumerate(names) if n == "magline_waiting" and w == "the hook test's wait")
    assert last_tick < names.index(("magline_wait_ended", "the hook test's wait"))


def test_magline_motion_started(heard):
    listener, record = heard
    started = listener.of("magline_motion_started")
    assert [c["round"] for c in started] == list(range(1, len(record.attempts) + 1))
    assert {c["motion"] for c in started} == {"operator"}


def test_magline_motion_stopped(heard):
    listener, _ = heard
    assert [c["round"] for c in listener.of("magline_motion_stopped")] == \
        [c["round"] for c in listener.of("magline_motion_started")]


def test_magline_operator_prompt(heard):
    listener, record = heard
    prompts = listener.of("magline_operator_prompt")
    assert len(prompts) == len(record.attempts) and all(c["message"] for c in prompts)


def test_magline_unit_started(heard):
    """Heard in identify, after the results store listener began the run (it answered: run id set)."""
    listener, record = heard
    (started,) = listener.of("magline_unit_started")
    assert started["phase"] == "identify" and started["run_id"] == record.run_id is not None


def test_magline_attempt_ended(heard):
    """Each attempt, before anything is fitted, with its raw readings: the store kept them (the
    stored run shows them)."""
    listener, record = heard
    ended = listener.of("magline_attempt_ended")
    assert all(c["attempt"] is a for c, a in zip(ended, record.attempts, strict=True))
    assert not any(c["fitted"] for c in ended)
    assert all(len(c["attempt"].raw) == c["attempt"].samples > 0 for c in ended)


def test_magline_record_unit(heard):
    """In the record phase with the final verdict; every store's answer is in ``record.store``."""
    listener, record = heard
    (recorded,) = listener.of("magline_record_unit")
    assert recorded["verdict"] is Outcome.PASS and recorded["finished"]
    assert "results.sqlite" in record.store and "the hook test's ledger" in record.store


def test_magline_unit_judged(heard):
    listener, record = heard
    (judged,) = listener.of("magline_unit_judged")
    assert "hard_iron_norm_ut" in judged["names"] and record.verdict is Outcome.PASS


def test_magline_unit_finished(heard):
    listener, record = heard
    (finished,) = listener.of("magline_unit_finished")
    assert finished["record"] is record and record.store  # stored before the listeners hear it
    assert listener.calls[-1][0] == "magline_unit_finished"


# ----------------------------------------------------------------------------------- the guard
def test_every_hook_has_a_test_named_for_it_and_its_signature_in_the_reference():
    tests = {name for name in globals() if name.startswith("test_magline_")}
    assert {f"test_{h}" for h in HOOKS} == tests
    reference = (REPO / "docs" / "plugins.md").read_text(encoding="utf-8")
    missing = [h for h in HOOKS if _signature(getattr(hookspecs, h)) not in reference]
    assert missing == []


def test_magline_operator_confirm():
    """``firstresult``: a listener with nobody to ask answers None and the next is asked; the first yes or
    no is the answer; nobody at all answers None (the caller refuses: no motor test, issue 46)."""

    class Nobody:
        @hookimpl
        def magline_operator_confirm(self, run, question, timeout_s):
            return None

    class Says:
        def __init__(self, answer):
            self.answer = answer

        @hookimpl
        def magline_operator_confirm(self, run, question, timeout_s):
            return self.answer

    ask = {"run": None, "question": "Are the propellers off?", "timeout_s": 1.0}
    assert load_plugins(extra=[Says(False), Nobody()]).hook.magline_operator_confirm(**ask) is False
    assert load_plugins(extra=[Says(True), Nobody()]).hook.magline_operator_confirm(**ask) is True
    assert load_plugins(extra=[Nobody()]).hook.magline_operator_confirm(**ask) is None


def test_magline_tilt_guidance(tmp_path):
    """A turntable's guidance, heard by a listener: a motion that ``TurnsForTilts`` (here a table that
    turns at once) makes the acquisition ask for tilts; the mock unit in the operator's hands never holds
    still, so the first tilt (level) is asked, with its picture's angles, and never taken."""
    from magline.plugin import Tilt

    shown: list[str] = []
    heard: list[dict] = []

    class Table:
        type = "hook-table"
        tolerance_deg, settle_s, tilt_timeout_s = 15.0, 0.2, 30.0

        def __init__(self):
            self.tilts = [Tilt(0.0, 0.0), Tilt(-45.0, 0.0, "nose down")]

        def start(self, round, slots): ...
        def stop(self): ...
        def close(self): ...
        def show(self, words, tilt): shown.append(words)
        def turn(self): ...
        def turning(self): return False

    class Plugin:
        @hookimpl
        def magline_register_motions(self, register):
            register("hook-table", lambda station, folder, options: Table())

        @hookimpl
        def magline_tilt_guidance(self, run, guidance):
            heard.append(guidance)

    record = run_with(tmp_path, Plugin(), changes={"motion": {"type": "hook-table"}})
    assert record.attempts and heard
    first = heard[0]
    assert first["state"] == "tilt" and first["asked"] == "level" and first["step"] == 1
    assert (first["pitch_deg"], first["roll_deg"]) == (0.0, 0.0) and first["found"] is None
    assert shown[0] == "Tilt the cradle: level"
