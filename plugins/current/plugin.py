"""Registers the current sources of the interference sweep: ``electronic-load``, ``bench-supply`` and
``motor-test``."""

from __future__ import annotations

from magline.plugin import hookimpl


@hookimpl
def magline_register_current_sources(register):
    from magline.plugins.current.electronic_load import (
        BenchSupplyOptions,
        ElectronicLoadOptions,
        create_bench_supply,
        create_electronic_load,
    )
    from magline.plugins.current.motor_test import MotorTestOptions, create_motor_test

    register("electronic-load", create_electronic_load, options=ElectronicLoadOptions)
    register("bench-supply", create_bench_supply, options=BenchSupplyOptions)
    register("motor-test", create_motor_test, options=MotorTestOptions)
