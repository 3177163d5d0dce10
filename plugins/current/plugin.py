"""Registers the current sources of the interference sweep: ``electronic-load``, ``bench-supply`` and
``motor-test``."""

from __future__ import annotations

from magline.plugin import hookimpl


@hookimpl
def magline_register_current_sources(register):
    # named by place: each source's module is imported when a station file uses it
    register("electronic-load", "magline.plugins.current.electronic_load:create_electronic_load",
             options="magline.plugins.current.electronic_load:ElectronicLoadOptions")
    register("bench-supply", "magline.plugins.current.electronic_load:create_bench_supply",
             options="magline.plugins.current.electronic_load:BenchSupplyOptions")
    register("motor-test", "magline.plugins.current.motor_test:create_motor_test",
             options="magline.plugins.current.motor_test:MotorTestOptions")
