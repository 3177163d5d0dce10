"""Motions: what turns the units while they are sampled (an operator's tumble, a motorised gimbal).

Why a concept of its own: on a station with several slots the units share one motion, so it must be
started once for all of them and stopped only when the last one has its samples (see
:mod:`magline.core.sequencer.rounds`); on a one-unit station it is started around each attempt.
"""

from __future__ import annotations

from typing import Protocol


class Motion(Protocol):
    """A fixture motion.  ``start`` returns once the fixture moves (raise a
    :class:`~magline.plugin.StationFault` when it cannot: the slots of the round are then not
    judged); ``stop`` is called once per started round, also after errors."""

    type: str

    def start(self, round: int, slots: list[str]) -> None: ...

    def stop(self) -> None: ...

    def close(self) -> None: ...
