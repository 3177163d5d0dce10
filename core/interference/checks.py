"""The interference figures a unit is judged on (a ``magline_validate_unit`` listener, entry point
``interference``): per compass its share of the field at the product's current, its field per amp with
σ, its linearity and its return to zero; for the unit its current sensor against the load's."""

from __future__ import annotations

from typing import TYPE_CHECKING

from magline.core.measurements import Json, Measurement, Numeric, Verdict
from magline.core.plugins import hookimpl

if TYPE_CHECKING:
    from magline.core.fit import FitResult
    from magline.core.sequencer.context import RunContext


@hookimpl
def magline_validate_unit(run: RunContext, fits: dict[int, FitResult]) -> list[Measurement]:
    found = run.interference
    if found is None:
        return []
    from magline.core.interference.model import zone_words  # here: every command loads this plugin

    out: list[Measurement] = []
    for sensor in run.magnetometers:
        compass = found.compasses.get(sensor.device_id)
        if compass is None:
            continue
        prefix = run.sensor_prefix(sensor.device_id)
        label = run.sensor_label(sensor.device_id)
        pct = Numeric.of(prefix + "interference_pct_at_max", compass.pct_at_max, run.limits)
        if pct.verdict in (Verdict.REVIEW, Verdict.FAIL):
            pct.note = (f"{label}: {compass.pct_at_max:.0f} % of the field at {found.current_max_a:g} A — "
                        f"{zone_words(compass.pct_at_max)}")
        out += [pct, Numeric.of(prefix + "interference_ut_per_a", compass.ut_per_a, run.limits),
                Numeric.of(prefix + "interference_sigma_ut_per_a", compass.per_amp_sigma_ut, run.limits),
                Numeric.of(prefix + "interference_linearity_ut", compass.linearity_ut, run.limits),
                Numeric.of(prefix + "interference_return_ut", compass.return_ut, run.limits)]
    if found.sensor_error_pct is not None:
        error = Numeric.of("current_sensor_error_pct", found.sensor_error_pct, run.limits)
        if error.verdict is Verdict.FAIL:
            error.note = (f"the unit's current sensor reads {found.sensor_error_pct:+.1f} % against the load: its "
                          "scale (ArduPilot BATT_AMP_PERVLT, PX4 BAT1_A_PER_V) is wrong")
        out.append(error)
    out.append(Json(name="interference", data=found.to_dict()))
    return out
