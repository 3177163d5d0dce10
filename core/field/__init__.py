"""Field sources: the expected local field the calibrated sphere must match.

A field source is created once per station run (``factory(station)``) and asked for the
reference at every unit.  Sources: ``fixed`` (a surveyed magnitude), ``wmm`` (the World Magnetic
Model at the station's place and date), both optionally checked against a live fluxgate
(:mod:`.reference`); ``helmholtz`` (``plugins/helmholtz``) generates the field itself.  Optional
attribute ``moves_unit`` (default True): False for a source that turns the field round a unit
standing still (a coil), so the operator is not told to stop moving it.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from magline.core.faults import StationFault


class FieldSourceError(StationFault):
    """The cell's field cannot be trusted (reference disagrees with the model, drifts, coil fault).

    The sequencer stops the batch: no further unit is calibrated until the station is restarted
    after the cause is fixed.
    """


@runtime_checkable
class FieldSource(Protocol):
    def reference_field_ut(self) -> float:
        """The field magnitude a unit about to be calibrated must see (µT); raises
        :class:`FieldSourceError` when the cell is not fit to calibrate in."""

    def finish_unit(self) -> None:
        """The unit's run ended (also after errors): leave the source safe (e.g. coil off)."""

    def close(self) -> None: ...
