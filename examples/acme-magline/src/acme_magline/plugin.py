"""Registers the ``acme`` DUT backend and the ``jsonl`` results sink, each with its options model
(``magline check`` then validates them with file, key and line), and the plugin's own measurement,
``acme_board_temp_c``: a station file may limit it (``limits: {acme_board_temp_c: {le: 60}}``).

The backend and the sink are imported when first used, their options models named by where they live: every
``magline`` command loads this module, and the board's driver (with its NumPy) would cost each one's start,
``magline --help`` included, on every station of the plant — most of which never name ``acme``."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from magline.plugin import hookimpl

if TYPE_CHECKING:
    from acme_magline.dut import AcmeDut, AcmeOptions
    from acme_magline.sink import JsonLinesOptions, JsonLinesSink


def create_acme_dut(product, options: AcmeOptions) -> AcmeDut:
    from acme_magline.dut import AcmeDut

    return AcmeDut(options, product.connection)


def create_jsonl_sink(station, station_dir: Path, entry, options: JsonLinesOptions) -> JsonLinesSink:
    from acme_magline.sink import JsonLinesSink

    return JsonLinesSink(Path(station_dir) / options.path, raw=options.raw)


@hookimpl
def magline_register_dut_backends(register):
    register("acme", create_acme_dut, options="acme_magline.dut:AcmeOptions")


@hookimpl
def magline_register_measurements(register):
    register("acme_board_temp_c", unit="°C", meaning="the board's own temperature after the tumble (a board "
             "running hot has a part drawing too much current)", possible=(-60.0, 150.0))


@hookimpl
def magline_validate_unit(run, fits):
    """Every product's units are heard: an ACME board's temperature, the others' nothing."""
    if run.product.backend != "acme":
        return []
    return [run.measured("acme_board_temp_c", run.require_dut().board_temp_c())]


@hookimpl
def magline_register_result_sinks(register):
    register("jsonl", create_jsonl_sink, options="acme_magline.sink:JsonLinesOptions")
