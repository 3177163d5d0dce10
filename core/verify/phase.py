"""The default verify phase (entry point ``core_verify``): power-cycle the unit through the station's
power control, prove the new boot, read every written parameter back, ask the firmware what it says
is wrong, prove the calibration it applies (:mod:`.calibrated_output`), and where the product keeps it
in the firmware's factory store, prove the store (:mod:`.factory_store`).  ``trylast``: a plugin
implementing ``magline_verify_persistence`` replaces it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from magline.core.dut import (
    HasBootTimeout,
    ReportsSensorsPresent,
    param_equal,
)
from magline.core.plugins import hookimpl
from magline.core.record import VerifyReport

if TYPE_CHECKING:
    from magline.core.record import PersistReport
    from magline.core.sequencer.context import RunContext


@hookimpl(trylast=True)
def magline_verify_persistence(run: RunContext, persisted: PersistReport) -> VerifyReport:
    # on use: every command loads this plugin, and the proofs' arithmetic needs NumPy
    from magline.core.verify.calibrated_output import calibrated_output_problems
    from magline.core.verify.factory_store import factory_store_problems

    dut = run.require_dut()
    power = run.require_power()
    boot_timeout_s = dut.boot_timeout_s if isinstance(dut, HasBootTimeout) else None
    with run.waiting("power cycle: waiting for the unit to boot", boot_timeout_s):
        figures = dict(power.cycle(dut))
    method = str(figures.pop("method", power.method))
    missing: list[str] = []
    if len(run.magnetometers) > 1 and isinstance(dut, ReportsSensorsPresent):
        now = set(dut.sensors_present())
        missing = [run.sensor_label(m.device_id) for m in run.magnetometers if m.device_id not in now]
        present = not missing
    else:
        present = dut.selected_sensor_present()
    read_back = dut.read_params(list(persisted.written))
    mismatches = [f"{k}: wrote {v!r}, read back {read_back.get(k)!r}" for k, v in persisted.written.items()
                  if k not in read_back or not param_equal(v, read_back[k])]
    if present:  # the calibrated output first: a backend may start its own checks at the boot, read them after
        mismatches += calibrated_output_problems(run, dut, figures)
        mismatches += [f"autopilot reports: {text}" for text in dut.persistence_problems()]
    store_problems, store = factory_store_problems(run, dut, persisted) if not mismatches and present else ([], "")
    mismatches += store_problems
    return VerifyReport(read_back=read_back, mismatches=mismatches, sensor_present=present,
                        method=method, figures={k: float(v) for k, v in figures.items()}, missing=missing,
                        store=store)
