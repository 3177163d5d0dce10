"""Plugin discovery: entry points, third-party DUTs, disabling, misspelt hooks, listing."""

from __future__ import annotations

import json
import sys
import textwrap
from typing import ClassVar

import pytest
from conftest import installed_plugin

from magline.core.cli import main
from magline.core.plugins import PluginError, hookimpl, load_plugins
from magline.core.record import Outcome
from magline.core.sequencer import Sequencer
from magline.core.station import load_station


@pytest.fixture
def third_party(tmp_path, monkeypatch):
    """A tiny installed distribution with a ``magline`` entry point adding DUT backend 'acme'."""
    site = tmp_path / "site"
    installed_plugin(site, "acme_magline", "acme-magline", "1.0", textwrap.dedent('''
        from magline.core.plugins import hookimpl
        from magline.plugins.mock.options import MockOptions
        from magline.plugins.mock.plugin import create_mock_dut

        CREATED = []

        def make(product, options):
            CREATED.append(product.connection)
            return create_mock_dut(product, options)

        @hookimpl
        def magline_register_dut_backends(register):
            register("acme", make, options=MockOptions)

        def hello(args):
            print(f"acme says hello to {args.who}")
            return 5

        @hookimpl
        def magline_add_commands(subparsers):
            cmd = subparsers.add_parser("acme-hello", help="third-party command")
            cmd.add_argument("who")
            cmd.set_defaults(handler=hello)
    '''))
    monkeypatch.syspath_prepend(str(site))
    yield site
    sys.modules.pop("acme_magline", None)


def test_third_party_backend_can_be_named_in_a_station(third_party, make_station, tmp_path):
    path = make_station({"products": {"MOCK-100": {"backend": "acme", "connection": "acme://bench-3"}}})
    plugins = load_plugins()
    assert "acme" in plugins.dut_backends
    seq = Sequencer(load_station(path), plugins, tmp_path, sleep=lambda s: None)
    record = seq.run_unit("TP-1")
    seq.close()
    assert record.verdict is Outcome.PASS
    import acme_magline
    assert acme_magline.CREATED == ["acme://bench-3"]


def test_third_party_plugin_adds_a_command_line_command(third_party, capsys):
    """magline_add_commands: the plugin's sub-command runs and its exit code is returned."""
    assert main(["acme-hello", "line 3"]) == 5
    assert "acme says hello to line 3" in capsys.readouterr().out


def test_builtins_load_through_the_entry_point_group():
    names = {d["name"] for d in load_plugins().describe()}
    assert {"core_phases", "sqlite_results", "fixed_field", "mock"} <= names


def test_disable_plugins_by_name(monkeypatch, make_station, capsys):
    monkeypatch.setenv("MAGLINE_DISABLE_PLUGINS", "mock")
    assert "mock" not in load_plugins().dut_backends
    assert main(["check", str(make_station())]) == 2
    assert "unknown DUT backend 'mock'" in capsys.readouterr().err


def test_misspelt_hook_is_rejected_at_start_up():
    class Typo:
        @hookimpl
        def magline_validat(self, run, fit):
            return []

    with pytest.raises(PluginError, match="magline_validat"):
        load_plugins(extra=[Typo()])


def test_duplicate_backend_name_rejected():
    class Dup:
        @hookimpl
        def magline_register_dut_backends(self, register):
            register("mock", lambda product, options: None)

    with pytest.raises(PluginError, match=r"registered twice \(by plugin 'Dup' and by plugin 'mock'\)"):
        load_plugins(extra=[Dup()])


def test_a_registration_left_for_later_fails_at_every_use_and_never_serves_half_a_registry():
    """``magline`` registers the plugins once its command line is parsed (its help needs none of it): a
    name registered twice is then said at the first use of any registry, and at every later one — the
    backends registered before the failure are no registry to run a unit with."""
    class Dup:
        @hookimpl
        def magline_register_dut_backends(self, register):
            register("mock", lambda product, options: None)

    plugins = load_plugins(extra=[Dup()], register=False)  # loading alone registers nothing
    for _ in range(2):
        with pytest.raises(PluginError, match="registered twice"):
            plugins.dut_backends  # noqa: B018 — the use is the test
    with pytest.raises(PluginError, match="registered twice"):
        plugins.field_sources  # noqa: B018


def test_plugins_command_lists_hooks(capsys):
    assert main(["plugins"]) == 0
    doc = json.loads(capsys.readouterr().out)
    core = next(p for p in doc["plugins"] if p["name"] == "core_phases")
    assert "magline_fit" in core["hooks"] and "mock" in doc["dut_backends"]
    from magline.core import __version__

    px4 = doc["registered"]["dut backend"]["px4"]
    assert px4 == {"plugin": "px4", "distribution": "magline", "version": __version__, "options": "Px4Options"}
    gimbal = next(p for p in doc["plugins"] if p["name"] == "gimbal")
    assert gimbal["registers"] == ["motion: gimbal"] and gimbal["version"] == __version__


def test_fit_hook_can_be_replaced_by_a_plugin(make_station, tmp_path):
    from magline.core.fit import FitRefused

    class NoFit:
        @hookimpl
        def magline_fit(self, run, samples, options):
            raise FitRefused("custom", "custom fitter says no", "call engineering")

    record = Sequencer(load_station(make_station()), load_plugins(extra=[NoFit()]), tmp_path,
                       sleep=lambda s: None).run_unit("F1")
    assert record.verdict is Outcome.FAIL and "custom fitter says no" in record.cause


def test_acquire_persist_and_verify_hooks_can_be_replaced(make_station, tmp_path, rng):
    """A replay plugin feeds recorded samples; a persist plugin and a verify plugin take over."""
    import numpy as np

    from magline.core.fit.samples_csv import RawSamples
    from magline.core.record import PersistReport, VerifyReport
    from magline.core.sequencer import Acquisition
    from magline.sim.truth import earth_field_ned, motion_directions, random_truth

    truth = random_truth(rng, max_offset_ut=40.0)
    d = motion_directions("full_sphere", 600, rng, earth_field_ned(48.0, 63.0))
    recorded = truth.read(d * 48.0, rng)

    class Replay:
        calls: ClassVar[list] = []

        @hookimpl
        def magline_acquire(self, run, attempt):
            self.calls.append(("acquire", attempt))
            return Acquisition(attempt=attempt, samples=RawSamples(mag_ut=recorded, t_ms=np.arange(600) * 10.0),
                               coverage=1.0, target=0.6)

        @hookimpl
        def magline_persist(self, run, fit):
            self.calls.append(("persist", round(float(fit.hard_iron_ut[0]), 1)))
            return PersistReport(before={"X": 0.0}, written={"X": 1.0}, echoed={"X": 1.0})

        @hookimpl
        def magline_verify_persistence(self, run, persisted):
            self.calls.append(("verify", persisted.written["X"]))
            return VerifyReport(read_back={"X": 0.0}, mismatches=["X: wrote 1.0, read back 0.0"],
                                sensor_present=True, method="replay")

    replay = Replay()  # recorded magnetometer readings only: no accelerometer to prove the mounting with
    station = make_station({"products": {"MOCK-100": {"orientation": "skip"}}})
    record = Sequencer(load_station(station), load_plugins(extra=[replay]), tmp_path,
                       sleep=lambda s: None).run_unit("R1")
    assert replay.calls == [("acquire", 1), ("persist", round(float(record.calibration["hard_iron_ut"][0]), 1)),
                            ("verify", 1.0)]
    assert abs(record.calibration["hard_iron_ut"][0] - truth.hard_iron_ut[0]) < 0.2
    assert record.verdict is Outcome.FAIL and "X: wrote 1.0, read back 0.0" in record.cause
    assert record.persistence["method"] == "replay"


def test_a_plugins_path_option_is_read_beside_the_station_file_as_the_stations_own_paths_are(tmp_path):
    """A third-party backend declares its file option ``StationPath``: written relative in a station file, it
    arrives resolved against that file's folder, whatever folder the station was started from; absolute stays
    as written; validated without a station (a plugin's own tests building the model) it stays as written."""
    from pydantic import BaseModel, ConfigDict

    from magline.plugin import StationPath

    class TableOptions(BaseModel):
        model_config = ConfigDict(extra="forbid", strict=True)
        table: StationPath

    class Acme:
        @hookimpl
        def magline_register_dut_backends(self, register):
            register("acme-table", lambda product, options: None, options=TableOptions)

    plugins = load_plugins(extra=[Acme()])
    line = tmp_path / "line-2"
    read = plugins.options("dut backend", "acme-table", {"table": "cal/table.csv"}, "products.P.options", line)
    assert read.table == str(line / "cal" / "table.csv")
    absolute = str(tmp_path / "elsewhere.csv")
    assert plugins.options("dut backend", "acme-table", {"table": absolute}, "o", line).table == absolute
    assert TableOptions(table="cal/table.csv").table == "cal/table.csv"
    with pytest.raises(ValueError, match=r"options\.table"):
        plugins.options("dut backend", "acme-table", {"table": 3}, "products.P.options", line)


@pytest.fixture
def placed(tmp_path, monkeypatch):
    """An installed distribution whose backend names its factory and options model by place
    (``"package.module:Name"``), their module apart from the one its entry point loads."""
    site = tmp_path / "site"
    installed_plugin(site, "placed_magline", "placed-magline", "2.1", textwrap.dedent('''
        from magline.core.plugins import hookimpl

        @hookimpl
        def magline_register_dut_backends(register):
            register("placed", "placed_magline.backend:create", options="placed_magline.backend:PlacedOptions")
    '''))
    (site / "placed_magline" / "backend.py").write_text(textwrap.dedent('''
        from magline.plugins.mock.options import MockOptions
        from magline.plugins.mock.plugin import create_mock_dut

        CREATED = []

        class PlacedOptions(MockOptions):
            bench: str = "bench-1"

        def create(product, options):
            CREATED.append(options.bench)
            return create_mock_dut(product, options)
    '''), encoding="utf-8")
    monkeypatch.syspath_prepend(str(site))
    yield site
    for name in ("placed_magline", "placed_magline.backend"):
        sys.modules.pop(name, None)


def test_a_factory_and_options_model_named_by_place_are_imported_when_a_station_uses_them(
        placed, make_station, tmp_path, capsys):
    """Registering, listing and checking a station that names other backends import nothing of the plugin's
    module; a station naming the backend has its options checked against the model (file, key and line), and
    a unit runs through the factory."""
    plugins = load_plugins()
    assert "placed" in plugins.dut_backends and "placed_magline.backend" not in sys.modules
    assert main(["plugins"]) == 0
    listed = json.loads(capsys.readouterr().out)["registered"]["dut backend"]["placed"]
    assert listed["options"] == "PlacedOptions" and listed["version"] == "2.1"
    assert main(["check", str(make_station())]) == 0
    assert "placed_magline.backend" not in sys.modules

    wrong = make_station({"products": {"MOCK-100": {"backend": "placed", "options": {"bench": 3}}}}, name="w.yaml")
    assert main(["check", str(wrong)]) == 2
    assert "w.yaml:" in (err := capsys.readouterr().err) and "products.MOCK-100.options.bench" in err
    path = make_station({"products": {"MOCK-100": {"backend": "placed", "options": {"bench": "bench-7"}}}})
    seq = Sequencer(load_station(path), load_plugins(), tmp_path, sleep=lambda s: None)
    record = seq.run_unit("PL-1")
    seq.close()
    import placed_magline.backend

    assert record.verdict is Outcome.PASS and placed_magline.backend.CREATED == ["bench-7"]


@pytest.mark.parametrize(("factory", "options", "said"), [
    ("placed_magline.backend.create", None, r"the factory of dut backend 'odd' is named 'placed_magline.backend"
                                            r"\.create'; a factory is a callable or 'package.module:function'"),
    (lambda product, options: None, "placed_magline.backend", r"a model is named 'package.module:Class'"),
    (lambda product, options: None, {"bench": str}, r"must be a pydantic model class or 'package.module:Class', "
                                                    r"not dict"),
    ("placed_magline.backend", None, r"a factory is a callable"),
])
def test_a_place_of_the_wrong_form_is_refused_at_registration_naming_the_plugin(factory, options, said):
    class Odd:
        @hookimpl
        def magline_register_dut_backends(self, register):
            register("odd", factory, options=options)

    with pytest.raises(PluginError, match=r"plugin 'Odd': .*" + said):
        load_plugins(extra=[Odd()])


@pytest.mark.parametrize(("options", "said"), [
    ("placed_magline.gone:PlacedOptions", r"cannot be imported: ModuleNotFoundError: No module named "
                                          r"'placed_magline.gone'"),
    ("placed_magline.backend:Missing", "cannot be imported: AttributeError"),
    ("placed_magline.backend:create", "is not a pydantic model"),
])
def test_a_place_that_names_no_model_is_an_error_of_the_plugin_when_a_station_uses_it(
        placed, make_station, capsys, options, said):
    """The form is right, what it names is not: the first station naming the backend is refused by ``magline
    check`` with the plugin and the place, not a traceback, and a station that does not name it is unharmed."""
    class Odd:
        @hookimpl
        def magline_register_dut_backends(self, register):
            register("odd", "placed_magline.backend:create", options=options)

    from magline.core.station import read_station_text, station_problems

    plugins = load_plugins(extra=[Odd()])
    good = make_station()
    assert station_problems(read_station_text(good), str(good), plugins)[1] == []
    odd = make_station({"products": {"MOCK-100": {"backend": "odd"}}}, name="o.yaml")
    with pytest.raises(PluginError, match=rf"plugin 'Odd': the options model '{options}' of dut backend 'odd' "
                                          + said):
        station_problems(read_station_text(odd), str(odd), plugins)


def test_a_factory_whose_place_names_nothing_fails_the_unit_with_the_plugin_named(placed):
    class Odd:
        @hookimpl
        def magline_register_dut_backends(self, register):
            register("odd", "placed_magline.backend:gone")

    factory = load_plugins(extra=[Odd()]).dut_backends["odd"]
    with pytest.raises(PluginError, match=r"plugin 'Odd': the factory 'placed_magline.backend:gone' of dut backend "
                                          r"'odd' cannot be imported: AttributeError"):
        factory(None, {})
