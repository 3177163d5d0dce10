"""``motor-test``: the interference sweep's current drawn by the unit's own motors (MAVLink
MAV_CMD_DO_MOTOR_TEST), for lines without an electronic load.

Safety first: a motor test never runs unless the product's entry says ``motor_test: true`` (the station
file refuses the source otherwise) and, for every unit, something confirms the propellers are off: the
fixture's interlock — ``interlock_command`` run before the first spin must exit 0 (a switch the cradle
closes only without props, read by a script) — or, without one, the operator's yes at the terminal or
the station screen (``magline_operator_confirm``; no answer in time is a no, nobody to ask an ERROR).
The motors spin one at a time at a fraction of ``throttle_max_pct``, each step re-issued so no step
outlives its test, and are stopped at every end, also after errors.  The current is the unit's own
reading: no independent measurement, so the unit's current sensor is not checked
(``current_sensor_error_pct`` needs a load).
"""

from __future__ import annotations

import shlex
import subprocess
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

from pydantic import BaseModel, ConfigDict, Field

from magline.plugin import CurrentSourceError, DutError, RunsMotorTest

if TYPE_CHECKING:
    from magline.plugin import CurrentSourceConfig, RunContext

STOP_S = 1.0  # a 0 % test of this length stops a spinning motor


PROPS_QUESTION = "Are the propellers off? The unit's motors will spin for the current sweep"


class MotorTestOptions(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, defer_build=True)
    interlock_command: str | None = None
    """A command that exits 0 only when the fixture says the propellers are off; none: the operator confirms
    it, every unit."""
    confirm_timeout_s: Annotated[float, Field(gt=0)] = 60.0
    """How long the operator has to confirm the propellers are off."""
    throttle_max_pct: Annotated[float, Field(gt=0, le=100)] = 60.0
    """The throttle of the sweep's top step; each motor spins at its fraction of it."""
    step_s: Annotated[float, Field(gt=0, le=60)] = 5.0
    """How long each step's spin is asked for."""
    interlock_timeout_s: Annotated[float, Field(gt=0)] = 10.0
    """The interlock command's run."""


class MotorTest:
    name = "motor-test"

    def __init__(self, options: MotorTestOptions, station_dir: Path) -> None:
        self.opts = options
        self.station_dir = station_dir
        self.dut: RunsMotorTest | None = None
        # a spin lasts the seconds it was asked for: the firmware stops the motor then (ArduCopter's motor
        # test times out; a new command while it runs sets the throttle and starts the timeout again)
        self.level_lasts_s = options.step_s

    def start(self, run: RunContext) -> None:
        if not run.product.motor_test:
            raise CurrentSourceError(f"product {run.part} does not allow a motor test (motor_test: true)")
        dut = run.require_dut()
        if not isinstance(dut, RunsMotorTest):
            raise CurrentSourceError(f"the {run.product.backend} backend cannot run a motor test")
        if self.opts.interlock_command is not None:
            self._interlock(run)
        else:
            self._ask(run)
        self.dut = dut

    def _ask(self, run: RunContext) -> None:
        answer = run.confirm(PROPS_QUESTION, self.opts.confirm_timeout_s)
        if answer is None:
            raise CurrentSourceError("nobody confirmed the propellers are off (no operator at a terminal or the "
                                     "station screen, and no interlock_command): no motor test")
        if not answer:
            raise CurrentSourceError("the operator did not confirm the propellers are off: no motor test")

    def _interlock(self, run: RunContext) -> None:
        try:
            done = subprocess.run(shlex.split(self.opts.interlock_command), cwd=self.station_dir, capture_output=True,
                                  text=True, timeout=self.opts.interlock_timeout_s)
        except (OSError, subprocess.TimeoutExpired) as exc:
            raise CurrentSourceError(f"the propeller interlock could not be read ({exc}): no motor test") from exc
        if done.returncode != 0:
            said = (done.stdout + done.stderr).strip()[-200:]
            raise CurrentSourceError("the propeller interlock does not confirm the propellers are off (exit "
                                     f"{done.returncode}{': ' + said if said else ''}): no motor test")
        run.log("propeller interlock: propellers off")

    def set_level(self, fraction: float) -> None:
        if self.dut is None:
            raise CurrentSourceError("the motor test was not started")
        self._spin(min(max(fraction, 0.0), 1.0) * self.opts.throttle_max_pct)

    def _spin(self, throttle: float) -> None:
        """One motor at ``throttle`` % for a step (0 %: stopped — a short test at zero ends a running one)."""
        try:
            self.dut.motor_test(throttle, self.opts.step_s if throttle > 0 else STOP_S)
        except DutError as exc:
            raise CurrentSourceError(f"motor test at {throttle:.0f} %: {exc}") from exc

    def measured_current_a(self) -> float | None:
        return None  # the unit's own reading is the only one

    def stop(self) -> None:
        if self.dut is not None:
            try:
                self._spin(0.0)
            finally:
                self.dut = None

    def close(self) -> None:
        return None


def create_motor_test(config: CurrentSourceConfig, station_dir: Path, options: MotorTestOptions) -> MotorTest:
    return MotorTest(options, station_dir)
