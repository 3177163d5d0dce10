"""magline.testing, used the way a plugin author uses it: the fixtures from the installed pytest
plugin, the builders, check_station, the simulated vehicles and the results-sink conformance suite
run against magline's own stores."""

from __future__ import annotations

import numpy as np
import pytest

from magline.core.cli import main
from magline.core.plugins import load_plugins
from magline.core.record import Outcome
from magline.core.station import load_station
from magline.core.station.schema import Results
from magline.testing import (
    check_field_source,
    check_power_control,
    check_result_sink,
    check_station,
    make_fit,
    make_record,
    station_file,
)


def test_a_unit_on_a_kit_station_and_check_station_is_exactly_what_magline_check_prints(
        magline_station, magline_run, capsys):
    record = magline_run(magline_station(), "KIT-1")
    assert record.verdict is Outcome.PASS and record.serial == "KIT-1"
    bad = magline_station({"products": {"MOCK-100": {"options": {"colour": "red"}}}, "acquisition": {"samples": "x"}},
                          name="bad.yaml")
    problems = check_station(bad)
    assert main(["check", str(bad)]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [str(p) for p in problems]
    assert {(p.key, p.message.split(" (")[0]) for p in problems} == {
        ("acquisition.samples", "Input should be a valid integer"), ("products.MOCK-100.options.colour", "unknown key")}
    assert all(p.line > 1 for p in problems) and check_station(magline_station(name="good.yaml")) == []



def test_load_station_with_the_plugins_checks_what_only_they_know(magline_station):
    from magline.core.station import StationError

    path = magline_station({"products": {"MOCK-100": {"options": {"noise": 1.0}, "power": {"method": "relay"}}}})
    assert load_station(path).products["MOCK-100"].options["noise"] == 1.0  # the schema alone accepts it
    with pytest.raises(StationError) as refused:
        load_station(path, load_plugins())
    text = str(refused.value)
    assert "products.MOCK-100.options.noise: unknown key (did you mean 'noise_ut'?)" in text
    assert "products.MOCK-100.power.method: unknown power control 'relay'" in text



def test_make_fit_tests_a_conversion_without_hand_made_stand_ins():
    from magline.plugins.ardupilot.calibration import fit_to_params as ardupilot_params
    from magline.plugins.px4.calibration import fit_to_params as px4_params

    fit = make_fit([100.0, -50.0, 25.0], np.diag([1.1, 0.9, 1.0]), 48.0)
    assert fit.residual_rms_ut == 0.0 and fit.samples_used == 600 and fit.axis_ratio == pytest.approx(1.1 / 0.9)
    px4 = px4_params(fit, 0, 396809, 75, with_odiag=True)
    assert [px4[f"CAL_MAG0_{a}OFF"] for a in "XYZ"] == pytest.approx([1.0, -0.5, 0.25])  # Gauss
    ap = ardupilot_params(fit, "")
    assert [ap[f"COMPASS_OFS_{a}"] for a in "XYZ"] == pytest.approx([-1000.0, 500.0, -250.0])  # mGauss, added
    record = make_record(serial="X", verdict="fail", cause="why")
    assert (record.serial, record.verdict, record.cause) == ("X", Outcome.FAIL, "why")


def test_a_simulated_vehicle_from_the_kit_runs_a_station(magline_ardupilot, tmp_path, magline_run):
    fc = magline_ardupilot()
    path = station_file(tmp_path, {"products": {"AP-QUAD-200": {"connection": fc.connection, "options": {
        "connect_timeout_s": 5.0, "boot_timeout_s": 10.0, "prearm_wait_s": 0.3}}},
        "acquisition": {"samples": 300, "rate_hz": 200.0, "timeout_s": 30.0}}, base="ardupilot-sim.yaml")
    record = magline_run(path, "KIT-AP")
    assert record.verdict is Outcome.PASS, record.cause
    assert record.params_read_back and not fc.sim.errors


def test_magline_stores_meet_the_results_sink_contract(tmp_path, postgres, monkeypatch):
    plugins = load_plugins()
    station = load_station(station_file(tmp_path / "station"))
    check_result_sink(lambda folder: plugins.result_sinks["sqlite"](
        station, folder, Results(sink="sqlite", path="conformance.sqlite"), {}), tmp_path / "sqlite")
    monkeypatch.setenv("MAGLINE_CONFORMANCE_URL", postgres.new_database())
    check_result_sink(lambda folder: plugins.result_sinks["sql"](
        station, folder, Results(sink="sql", url_env="MAGLINE_CONFORMANCE_URL"), {}), tmp_path / "sql")


def test_the_conformance_suite_names_the_broken_rule(tmp_path):
    class Forgetful:
        """Keeps records in memory only: a new handle finds nothing."""

        def __init__(self):
            self.runs, self.next = {}, 0

        def begin(self, record):
            self.next += 1
            record.run_id = self.next

        def save_attempt(self, record, attempt):
            if record.run_id is None:
                self.begin(record)

        def finish(self, record):
            self.runs.setdefault(record.serial, []).append({"id": record.run_id})

        def history(self, serial):
            return self.runs.get(serial, [])

        def close(self):
            pass

    with pytest.raises(AssertionError, match="from a new handle on the store"):
        check_result_sink(lambda folder: Forgetful(), tmp_path)


def test_an_outside_project_gets_the_fixtures_from_the_installed_plugin(pytester):
    pytester.makepyfile(test_outside="""
        from magline.core.record import Outcome

        def test_uses_the_kit(magline_station, magline_run):
            assert magline_run(magline_station(), "OUT-1").verdict is Outcome.PASS
    """)
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider")  # in process it would reload sqlalchemy
    result.assert_outcomes(passed=1)


def test_magline_field_sources_meet_the_contract(magline_station):
    import datetime as dt

    from magline.core.field.wmm import wmm_field_nt

    plugins = load_plugins()
    fixed = load_station(magline_station())
    options = plugins.options("field source", "fixed", fixed.field_source.options, "field_source.options")
    check_field_source(lambda: plugins.field_sources["fixed"](fixed, options), expected_ut=48.0)
    wmm = load_station(magline_station(replace={"field_source": {"type": "wmm", "options": {"date": "2026-11-22"}}},
                                       name="wmm.yaml"))
    expected = wmm_field_nt(47.3769, 8.5417, 408.0, dt.date(2026, 11, 22))["f"] / 1000
    options = plugins.options("field source", "wmm", wmm.field_source.options, "field_source.options")
    check_field_source(lambda: plugins.field_sources["wmm"](wmm, options), expected_ut=expected, tolerance_ut=1e-6)


def test_magline_power_controls_meet_the_contract(magline_px4, tmp_path):
    from magline.core.power import LinkReboot
    from magline.plugins.mock.dut import MockDut
    from magline.plugins.mock.options import MockOptions
    from magline.plugins.power.scpi_supply import ScpiSupply, ScpiSupplyOptions
    from magline.plugins.px4.dut import Px4Dut
    from magline.plugins.px4.options import Px4Options
    from magline.sim.supply import SupplySim

    mock = MockOptions(storage=str(tmp_path / "nv.json"))
    assert check_power_control(LinkReboot, lambda: MockDut(mock))["method"] == "link-reboot"
    fc = magline_px4()
    station = load_station(station_file(tmp_path / "px4", {"products": {"PX4-X500-100": {"connection": fc.connection}}},
                                        base="px4-sim.yaml"))
    product = station.products["PX4-X500-100"]
    with SupplySim("tcp:127.0.0.1:0", board=fc.sim) as supply:
        figures = check_power_control(
            lambda: ScpiSupply(ScpiSupplyOptions(resource=supply.visa_resource, off_time_s=0.3, settle_s=0.1)),
            lambda: Px4Dut(product, Px4Options(connect_timeout_s=5.0, boot_timeout_s=10.0)))
    assert figures["method"] == "scpi-supply" and figures["uptime_at_reconnect_s"] < figures["time_to_heartbeat_s"]


def test_the_power_contract_catches_a_cycle_that_never_reboots(tmp_path):
    from magline.plugins.mock.dut import MockDut
    from magline.plugins.mock.options import MockOptions

    class Pretend:
        method = "pretend"

        def power_up(self):
            pass

        def cycle(self, dut):  # says it cycled; the unit never went away and its old boot answers
            return {"method": self.method, "time_to_heartbeat_s": 0.5, "uptime_at_reconnect_s": 120.0}

        def finish(self):
            pass

        def close(self):
            pass

    with pytest.raises(AssertionError, match="new boot"):
        check_power_control(Pretend, lambda: MockDut(MockOptions(storage=str(tmp_path / "nv.json"))))


def test_the_mock_dut_and_results_fixtures(magline_mock_dut, magline_results, magline_station, magline_run):
    dut = magline_mock_dut(hard_iron_ut=[1.0, 2.0, 3.0])
    info = dut.connect()
    assert info.autopilot == "mock" and dut.read_params(["MAG_OFS_X"]) == {"MAG_OFS_X": 0.0}
    station = magline_station()
    record = magline_run(station, "KIT-STORE")
    store = magline_results(station)
    try:
        (run,) = store.history("KIT-STORE")
        whole = store.run(run["id"])
        attempts = store.attempts("KIT-STORE")
    finally:
        store.close()
    assert run["verdict"] == "pass" and whole["params"]["written"] == record.params_written
    assert [a["samples"] for a in attempts] == [a.samples for a in record.attempts]
    assert attempts[-1]["raw"].mag_ut.shape == (record.attempts[-1].samples, 3)
