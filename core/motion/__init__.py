"""Motions: what turns the units while they are sampled (an operator's tumble, a motorised gimbal, a
turntable whose cradle the operator tilts between its turns).

Why a concept of its own: on a station with several slots the units share one motion, so it must be
started once for all of them and stopped only when the last one has its samples (see
:mod:`magline.core.sequencer.rounds`); on a one-unit station it is started around each attempt.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol, runtime_checkable

if TYPE_CHECKING:
    from magline.core.motion.tilts import Tilt


class Motion(Protocol):
    """A fixture motion.  ``start`` returns once the fixture moves (raise a
    :class:`~magline.plugin.StationFault` when it cannot: the slots of the round are then not
    judged); ``stop`` is called once per started round, also after errors."""

    type: str

    def start(self, round: int, slots: list[str]) -> None: ...

    def stop(self) -> None: ...

    def close(self) -> None: ...


@runtime_checkable
class TurnsForTilts(Protocol):
    """A turntable under a cradle the operator tilts: the acquisition asks for a tilt, proves it with
    each unit's accelerometer, then calls :meth:`turn` for one revolution and :meth:`turning` until it
    is done (:mod:`magline.core.motion.guided`).  ``start`` only readies the table; ``stop`` halts it.

    ``tilts``: the tilts the station file names, in order (None or empty: chosen by the coverage);
    ``tolerance_deg``: how far the accelerometer may disagree with the asked tilt; ``settle_s``: how long
    a tilt must be held (or a wrong one held, before it is named); ``tilt_timeout_s``: how long the
    operator has for a tilt before the tumble stalls.  ``turn`` and ``turning`` raise a
    :class:`~magline.plugin.StationFault` when the table cannot turn (stalled, lost); ``show`` puts the words
    asked and the tilt on the rig's own display, where it has one (a pendant), and does nothing otherwise."""

    tilts: list[Tilt] | None
    tolerance_deg: float
    settle_s: float
    tilt_timeout_s: float

    def show(self, words: str, tilt: Tilt) -> None: ...

    def turn(self) -> None: ...

    def turning(self) -> bool: ...
