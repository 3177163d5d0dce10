"""The factory calibration store proven after the power cycle (``persist: factory-storage``).

Why more than the parameters' read-back: the parameters a station reads after the power cycle come
from the user's parameter file, loaded over the factory store — they would read back right whether or
not the store holds the calibration.  So the store itself is read where the firmware lets a station
read it (PX4: ``bsondump /fs/mtd_caldata`` over the MAVLink shell), and, where the product asks
(``prove_factory_restore``), the calibration parameters are reset and the unit rebooted: what comes
back can only have come from the store.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

from magline.core.dut import DutBackend, ParamValue, StoresFactoryCalibration, param_equal

if TYPE_CHECKING:
    from magline.core.record import PersistReport
    from magline.core.sequencer.context import RunContext


def factory_store_problems(run: RunContext, dut: DutBackend, persisted: PersistReport) -> tuple[list[str], str]:
    """The mismatches of the factory store against what was written, and where the calibration is kept
    in words (for the record, ``magline show`` and the report)."""
    if persisted.store != "factory-storage":
        return [], "parameters (the autopilot parameter storage)"
    factory = persisted.factory or {}
    if not factory.get("written") or not isinstance(dut, StoresFactoryCalibration):
        return [], f"parameters only — the factory store was NOT written ({factory.get('said', 'not asked')})"
    problems: list[str] = []
    words = [f"factory calibration store, written ({factory.get('said')}), SYS_FAC_CAL_MODE left at "
             f"{factory.get('mode_after')}"]
    contents = dut.factory_store_contents(dict(persisted.written))
    if contents is None:
        words.append("its content not readable on this firmware")
    else:
        problems += _compared(persisted.written, contents, "the factory store holds")
        words.append(f"read back equal ({len(contents)} parameters)" if not problems else "read back DIFFERENT")
    if run.product.prove_factory_restore:
        with run.waiting("proving the factory store: calibration reset, reboot", None):
            restored = dut.restore_from_factory_store(time.monotonic())
        wrong = _compared(persisted.written, restored, "after a calibration reset and a reboot the unit came back with")
        problems += wrong
        words.append("given back after a calibration reset and a reboot" if not wrong
                     else "NOT given back after a calibration reset")
    return problems, "; ".join(words)


def _compared(written: dict[str, ParamValue], found: dict[str, ParamValue | None], what: str) -> list[str]:
    return [f"{what} {name} = {found.get(name)!r} (written {written[name]!r})" for name in found
            if name in written and (found[name] is None or not param_equal(written[name], found[name]))]
