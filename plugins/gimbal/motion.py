"""A motorised gimbal controller driven over SCPI (TCP socket or serial, through ``core.links.scpi``).

Commands (the controller's line protocol; ``magline sim gimbal`` speaks it):

* ``PATT:STAR <pattern>,<speed>`` starts a pattern (``TUMBLE``: a spherical spiral through every
  orientation; ``GIMBAL``: continuous yaw, stepped pitch) and keeps repeating it;
* ``PATT:STOP`` holds the platform where it is;
* ``PATT?`` answers ``<PATTERN>,<speed>,<start time>`` while moving, ``IDLE,...`` when held;
* ``SYST:ERR?`` the error queue, checked after every start and stop.
"""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field

from magline.plugin import InstrumentError, ScpiInstrument

if TYPE_CHECKING:
    from magline.plugin import Station


class GimbalOptions(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, defer_build=True)
    resource: str
    """The gimbal's controller, e.g. TCPIP0::10.0.0.12::5030::SOCKET."""
    pattern: Literal["tumble", "gimbal"] = "tumble"
    """``tumble``: a spherical spiral through every orientation; ``gimbal``: continuous yaw, stepped pitch."""
    speed: Annotated[float, Field(gt=0, le=10)] = 1.0
    """The pattern's pace, a multiple of its normal rate."""
    timeout_s: Annotated[float, Field(gt=0)] = 2.0
    """One SCPI reply."""


class GimbalMotion:
    type = "gimbal"

    def __init__(self, options: GimbalOptions) -> None:
        self.opts = options
        self.instrument = ScpiInstrument(options.resource, options.timeout_s)
        self.instrument.write("*CLS")
        self.instrument.write("PATT:STOP")  # a batch starts from a held platform
        self.instrument.check("stopping the gimbal at start-up")

    def start(self, round: int, slots: list[str]) -> None:
        self.instrument.write(f"PATT:STAR {self.opts.pattern.upper()},{self.opts.speed:g}")
        self.instrument.check(f"starting the {self.opts.pattern} pattern")
        state = self.instrument.query("PATT?")
        if not state.upper().startswith(self.opts.pattern.upper()):
            raise InstrumentError(f"{self.opts.resource}: the gimbal did not start its {self.opts.pattern} pattern "
                                  f"(it reports {state!r})")

    def stop(self) -> None:
        self.instrument.write("PATT:STOP")
        self.instrument.check("stopping the pattern")

    def close(self) -> None:
        with contextlib.suppress(InstrumentError):  # after a lost controller: nothing left to stop
            self.instrument.write("PATT:STOP")
        self.instrument.close()


def create_gimbal_motion(station: Station, station_dir: Path, options: GimbalOptions) -> GimbalMotion:
    return GimbalMotion(options)
