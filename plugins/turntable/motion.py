"""A motorised turntable (rotary stage) driven over SCPI — a TCP socket or a serial line, through the
face's :class:`~magline.plugin.ScpiInstrument` (pyvisa) — under a cradle the operator tilts.

The station turns the table one revolution at a time and asks for the cradle's tilt between the turns
(:class:`~magline.plugin.TurnsForTilts`; the core proves each tilt with the units' accelerometers).
Commands (the stage controller's line protocol; ``magline sim turntable`` speaks it):

* ``HOME`` finds the home switch, ``HOME?`` answers 1 once homed;
* ``ROT:SPE <°/s>``, ``ROT:DIR CW|CCW``, ``ROT:TURN <revolutions>`` starts turning, ``ROT:STOP`` halts;
* ``ROT:STAT?`` answers ``MOVING,<position °>,<speed °/s>`` or ``IDLE,<position °>,0`` (the position
  cumulative, as the stage counts it: a revolution adds 360);
* ``DISP:TEXT "<words>"`` and ``DISP:TILT <pitch>,<roll>``: the rig's pendant shows the tilt asked for;
* ``SYST:ERR?`` the error queue, checked after every command that changes something.
"""

from __future__ import annotations

import contextlib
import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field

from magline.plugin import InstrumentError, ScpiInstrument

if TYPE_CHECKING:
    from magline.plugin import Station, Tilt

REACHED = 0.9  # a table turning at this share of the asked speed has reached it


class TiltStep(BaseModel):
    """One tilt the station file names: the cradle's pitch (nose up +) and roll (right side down +), and
    the words the operator reads (made from the angles when left out)."""

    model_config = ConfigDict(extra="forbid", strict=True, defer_build=True)
    pitch_deg: Annotated[float, Field(ge=-90, le=90)] = 0.0
    """The cradle's pitch, nose up positive."""
    roll_deg: Annotated[float, Field(ge=-180, le=180)] = 0.0
    """The cradle's roll, right side down positive."""
    say: str = ""
    """What the operator is told (made from the angles when left out)."""


class TurntableOptions(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, defer_build=True)
    resource: str
    """The table's controller, e.g. TCPIP0::10.0.0.14::5050::SOCKET or ASRL/dev/ttyUSB0::INSTR."""
    speed_dps: Annotated[float, Field(gt=0, le=720)] = 60.0
    """The table's speed during a revolution."""
    direction: Literal["cw", "ccw"] = "cw"
    """The table's direction of turn."""
    tilts: list[TiltStep] | Literal["coverage"] = "coverage"
    """The cradle's tilts in order; ``coverage``: the station chooses each next tilt to cover what the sphere
    still lacks."""
    tolerance_deg: Annotated[float, Field(gt=0, le=45)] = 15.0
    """How far the accelerometer may read from the tilt asked for."""
    settle_s: Annotated[float, Field(ge=0)] = 1.0
    """A tilt held this long is taken (a wrong one is named to the operator)."""
    tilt_timeout_s: Annotated[float, Field(gt=0)] = 60.0
    """No tilt made by then: the tumble stalls."""
    spin_up_s: Annotated[float, Field(gt=0)] = 2.0
    """The table reaches its speed within this."""
    home_timeout_s: Annotated[float, Field(gt=0)] = 30.0
    """The table finds its home position within this."""
    timeout_s: Annotated[float, Field(gt=0)] = 2.0
    """One SCPI reply."""


class TurntableMotion:
    type = "turntable"

    def __init__(self, options: TurntableOptions) -> None:
        from magline.plugin import Tilt  # here: its NumPy would cost every command that loads the plugins

        self.opts = options
        self.tilts = None if options.tilts == "coverage" else [Tilt(t.pitch_deg, t.roll_deg, t.say)
                                                               for t in options.tilts]
        self.tolerance_deg, self.settle_s = options.tolerance_deg, options.settle_s
        self.tilt_timeout_s = options.tilt_timeout_s
        self.turns = 0
        self._turn_started = 0.0
        self._moved = False
        self._asked_deg, self._from_deg = 360.0, 0.0
        self.instrument = ScpiInstrument(options.resource, options.timeout_s)
        self.instrument.write("*CLS")
        self.instrument.write("ROT:STOP")  # a batch starts from a table at rest
        self.instrument.check("stopping the turntable at start-up")
        self._home()
        self._spin_check()

    def _home(self) -> None:
        """Before any unit is touched: a table that does not home is named, not turned blind."""
        if self.instrument.query("HOME?").strip() == "1":
            return
        advice = "check its home switch and that nothing blocks the table"
        self.instrument.write("HOME")
        try:
            self.instrument.check("homing the turntable")
        except InstrumentError as exc:
            raise InstrumentError(f"the turntable did not home ({exc}): {advice}") from None
        deadline = time.monotonic() + self.opts.home_timeout_s
        while self.instrument.query("HOME?").strip() != "1":
            if time.monotonic() > deadline:
                raise InstrumentError(f"{self.opts.resource}: the turntable did not home within "
                                      f"{self.opts.home_timeout_s:g} s: {advice}")
            time.sleep(0.1)

    def _spin_check(self) -> None:
        """Before any unit is touched: a quarter turn at the station's speed, which it must make."""
        self.turn(revolutions=0.25)
        try:
            while self.turning():
                time.sleep(0.05)
        finally:
            self.instrument.write("ROT:STOP")
        self.turns = 0

    # ------------------------------------------------------------------ Motion
    def start(self, round: int, slots: list[str]) -> None:
        """A round begins with the table at rest: the first tilt is asked before the first turn."""
        self.instrument.write("ROT:STOP")
        self.instrument.check("readying the turntable")

    def stop(self) -> None:
        self.instrument.write("ROT:STOP")
        self.instrument.check("stopping the turntable")

    def close(self) -> None:
        with contextlib.suppress(InstrumentError):  # after a lost controller: nothing left to stop
            self.instrument.write("ROT:STOP")
        self.instrument.close()

    # ------------------------------------------------------------------ TurnsForTilts
    def show(self, words: str, tilt: Tilt) -> None:
        """The rig's pendant shows what the operator is asked (its own words and the target angles), in
        the ASCII an SCPI line carries ("45 deg" for 45°)."""
        text = words.replace("°", " deg").replace('"', "'").encode("ascii", "replace").decode("ascii")
        self.instrument.write(f'DISP:TEXT "{text}"')
        self.instrument.write(f"DISP:TILT {tilt.pitch_deg:g},{tilt.roll_deg:g}")
        self.instrument.check("showing the tilt on the pendant")

    def turn(self, revolutions: float = 1.0) -> None:
        # where the stage is before it moves: read after the command, a loaded station saw it 76° into the
        # turn and called the finished turn "stopped after 284° of 360°"
        self._from_deg = self._status()[1]
        self.instrument.write(f"ROT:SPE {self.opts.speed_dps:g}")
        self.instrument.write(f"ROT:DIR {self.opts.direction.upper()}")
        self.instrument.write(f"ROT:TURN {revolutions:g}")
        self.instrument.check("starting a revolution")
        self.turns += 1
        self._turn_started, self._moved = time.monotonic(), False
        self._asked_deg = 360.0 * revolutions

    def turning(self) -> bool:
        """Whether the turn is still under way, judged by the stage's own position (how often it is asked
        does not matter); a table that does not reach its speed in ``spin_up_s``, or stops short, is
        stalled (an InstrumentError naming it: the station's fault, not the unit's)."""
        state, position, speed = self._status()
        turned = abs(position - self._from_deg)
        if turned >= REACHED * self._asked_deg and state == "IDLE":
            return False  # the turn is done
        self._moved = self._moved or abs(speed) >= REACHED * self.opts.speed_dps or turned > 0.05 * self._asked_deg
        if self._moved and state != "IDLE":
            return True
        if self._moved:
            raise InstrumentError(f"{self.opts.resource}: the turntable stopped after {turned:.0f}° of "
                                  f"{self._asked_deg:g}°: check that nothing blocks the table")
        if time.monotonic() - self._turn_started <= self.opts.spin_up_s:
            return True  # starting
        raise InstrumentError(f"{self.opts.resource}: the turntable did not reach {self.opts.speed_dps:g} °/s "
                              f"within {self.opts.spin_up_s:g} s (it reports {state.lower()} at {speed:g} °/s, "
                              f"{turned:.0f}° turned): stalled — check that nothing blocks the table")

    def _status(self) -> tuple[str, float, float]:
        answer = self.instrument.query("ROT:STAT?").strip()
        parts = answer.split(",")
        try:
            return parts[0].upper(), float(parts[1]), float(parts[2])
        except (IndexError, ValueError):
            raise InstrumentError(f"{self.opts.resource}: ROT:STAT? answered {answer!r}, not STATE,angle,speed") \
                from None


def create_turntable_motion(station: Station, station_dir: Path, options: TurntableOptions) -> TurntableMotion:
    return TurntableMotion(options)
