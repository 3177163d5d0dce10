"""What decides FAIL against ERROR: the unit was judged bad, or the station could not judge it.

Why one place: yield, first-pass yield and every statistic count FAIL as a bad unit.  A cable, a
dead supply or a crashed simulator must never be counted as a failed drone, so every exception a
phase raises is classified here, the same way for every backend and instrument:

* :class:`~magline.core.dut.DutError` — the unit's firmware refused the calibration, its
  magnetometer is missing, the calibration did not survive the power cycle: FAIL;
* :class:`StationFault` (and :class:`~magline.core.dut.LinkError`, a lost or absent link) — the
  station's own equipment, link or configuration stopped the judgement: ERROR;
* :class:`UnitAborted` — the operator (Ctrl-C, SIGTERM, the screen's Abort) stopped the unit.
"""

from __future__ import annotations


class StationFault(RuntimeError):
    """The station could not judge the unit: no or lost link, an instrument or supply fault, a
    timeout of the station's own equipment, a configuration the unit cannot be tested with."""


class StreamTooFast(StationFault):
    """A stream asked faster than the station's serial line carries; ``fits_hz`` is the fastest the same
    stream fits at.  Why its own class: a rate the station file states is refused with the figures, but
    a rate the station chose itself (the current sweep's default) is lowered to ``fits_hz`` instead."""

    def __init__(self, message: str, fits_hz: float) -> None:
        super().__init__(message)
        self.fits_hz = fits_hz


class UnitAborted(BaseException):
    """The operator stopped the unit.  A ``BaseException`` (like ``KeyboardInterrupt``) so that no
    plugin's ``except Exception`` swallows it; the sequencer restores the DUT and records it."""

    def __init__(self, reason: str = "aborted by the operator") -> None:
        super().__init__(reason)
        self.reason = reason
