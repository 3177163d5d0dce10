"""Registers the ``acme`` DUT backend and the ``jsonl`` results sink, each with its options model
(``magline check`` then validates them with file, key and line)."""

from __future__ import annotations

from pathlib import Path

from magline.plugin import hookimpl

from acme_magline.dut import AcmeDut, AcmeOptions
from acme_magline.sink import JsonLinesOptions, JsonLinesSink


def create_acme_dut(product, options: AcmeOptions) -> AcmeDut:
    return AcmeDut(options, product.connection)


def create_jsonl_sink(station, station_dir: Path, entry, options: JsonLinesOptions) -> JsonLinesSink:
    return JsonLinesSink(Path(station_dir) / options.path, raw=options.raw)


@hookimpl
def magline_register_dut_backends(register):
    register("acme", create_acme_dut, options=AcmeOptions)


@hookimpl
def magline_register_result_sinks(register):
    register("jsonl", create_jsonl_sink, options=JsonLinesOptions)
