"""The DUT-backend conformance suite of magline.testing run against magline's own backends: the
mock in process, PX4 and ArduPilot against their simulators over real MAVLink."""

from __future__ import annotations

import pytest

from magline.core.plugins import load_plugins
from magline.core.station import load_station
from magline.plugins.mock.dut import MockDut
from magline.plugins.mock.options import MockOptions
from magline.testing import check_dut_backend, station_file


def test_the_mock_backend_meets_the_contract(tmp_path):
    options = MockOptions(motions=["hand_tumble"], realtime=True, storage=str(tmp_path / "nv.json"), seed=4)
    figures = check_dut_backend(lambda: MockDut(options), options.field_ut, samples=400, rate_hz=200.0,
                                prepare_params=["MAG_AUTOCAL"], hard_iron_ut=options.hard_iron_ut)
    assert figures["fit"].residual_rms_ut < 1.0


def test_a_restore_that_writes_ram_only_is_caught(tmp_path, monkeypatch):
    """The plugin author's trap: prepare() changed RAM, the calibration's commit saved it."""
    def ram_only(self):
        if self._saved_autocal is not None:
            self.ram["MAG_AUTOCAL"], self._saved_autocal = self._saved_autocal, None

    monkeypatch.setattr(MockDut, "restore", ram_only)
    options = MockOptions(motions=["hand_tumble"], realtime=True, storage=str(tmp_path / "nv.json"), seed=4)
    with pytest.raises(AssertionError, match=r"restore\(\) must undo prepare\(\) in storage"):
        check_dut_backend(lambda: MockDut(options), options.field_ut, rate_hz=200.0, prepare_params=["MAG_AUTOCAL"])


def test_a_wrong_sign_in_the_conversion_is_caught(tmp_path, monkeypatch):
    convert = MockDut.calibration_params

    def wrong_sign(self, fit):
        params = convert(self, fit)
        return {k: (-v if k.startswith("MAG_OFS") else v) for k, v in params.items()}

    monkeypatch.setattr(MockDut, "calibration_params", wrong_sign)
    options = MockOptions(motions=["hand_tumble"], realtime=True, storage=str(tmp_path / "nv.json"), seed=4)
    with pytest.raises(AssertionError, match="wrong sign, unit or matrix convention"):
        check_dut_backend(lambda: MockDut(options), options.field_ut, rate_hz=200.0)


def test_a_stream_without_an_accelerometer_is_caught_unless_the_device_has_none(tmp_path):
    options = MockOptions(motions=["hand_tumble"], realtime=True, storage=str(tmp_path / "nv.json"), seed=4,
                          accelerometer=False)
    with pytest.raises(AssertionError, match="no accelerometer readings"):
        check_dut_backend(lambda: MockDut(options), options.field_ut, rate_hz=200.0)
    check_dut_backend(lambda: MockDut(options), options.field_ut, rate_hz=200.0, accelerometer=False)


def _backend(path, part):
    station, plugins = load_station(path), load_plugins()
    product = station.products[part]
    options = plugins.options("dut backend", product.backend, product.options, f"products.{part}.options")
    return lambda: plugins.dut_backends[product.backend](product, options)


def test_the_px4_backend_meets_the_contract_on_its_simulator(magline_px4, tmp_path):
    fc = magline_px4(mag_count=2)  # several magnetometers: each streams in SampleChunk.more
    path = station_file(tmp_path, {"products": {"PX4-X500-100": {"connection": fc.connection, "options": {
        "connect_timeout_s": 5.0, "boot_timeout_s": 10.0}}}}, base="px4-sim.yaml")
    mag = fc.sim.magnetometers[0]
    check_dut_backend(_backend(path, "PX4-X500-100"), fc.sim.field_ut, rate_hz=200.0,
                      prepare_params=["SENS_MAG_AUTOCAL"], hard_iron_ut=mag.hard_iron_ut, unsaved_writes="unspecified")


def test_the_ardupilot_backend_meets_the_contract_on_its_simulator(magline_ardupilot, tmp_path):
    fc = magline_ardupilot(mag_count=3)
    path = station_file(tmp_path, {"products": {"AP-QUAD-200": {"connection": fc.connection, "options": {
        "connect_timeout_s": 5.0, "boot_timeout_s": 10.0, "prearm_wait_s": 0.3}}}}, base="ardupilot-sim.yaml")
    mag = fc.sim.magnetometers[0]
    check_dut_backend(_backend(path, "AP-QUAD-200"), fc.sim.field_ut, rate_hz=200.0,
                      prepare_params=["COMPASS_LEARN"], hard_iron_ut=mag.hard_iron_ut, unsaved_writes="kept")


def test_a_backend_without_the_firmware_s_calibrated_output_is_told_what_to_declare_and_the_page_says_so(tmp_path):
    """The conformance suite requires a capability the core does without (``ReadsCalibratedField``): the
    contract page, generated from the same table the suite asserts from, marks it required."""
    from conftest import REPO

    from magline.testing.conformance import REQUIRED_DUT_CAPABILITIES

    class WithoutCalibratedOutput:
        """The mock backend without ``calibrated_field_ut`` (a new class: ``isinstance`` against a Protocol
        remembers the classes it has seen)."""

        def __init__(self, dut: MockDut) -> None:
            self._dut = dut

        def __getattr__(self, name: str):
            if name == "calibrated_field_ut":
                raise AttributeError(name)
            return getattr(self._dut, name)

    options = MockOptions(motions=["hand_tumble"], realtime=True, storage=str(tmp_path / "nv.json"), seed=4)
    with pytest.raises(AssertionError, match="declare ReadsCalibratedField's method: the firmware's own calibrated"):
        check_dut_backend(lambda: WithoutCalibratedOutput(MockDut(options)), options.field_ut, rate_hz=200.0,
                          prepare_params=["MAG_AUTOCAL"])
    page = (REPO / "docs" / "plugins.md").read_text(encoding="utf-8")
    for capability, why in REQUIRED_DUT_CAPABILITIES.items():
        section = page.split(f"### `magline.plugin.{capability.__name__}`")[1].split("### ")[0]
        assert f"*Required by `magline.testing.check_dut_backend`*: {why}." in section
