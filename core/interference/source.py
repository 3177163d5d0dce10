"""What draws the current of the interference sweep: the contract a current-source plugin meets.

Why a plugin point: a line measures with what it has — a programmable electronic load in the unit's
power path (the repeatable choice, and the only one that measures the current itself), or the unit's
own motors on a motor test, props off, for lines without a load.  The core asks for levels (a
fraction of the product's ``current_max_a``), never for a protocol; the plugins in
``plugins/current`` speak SCPI or MAVLink.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

from magline.core.faults import StationFault

if TYPE_CHECKING:
    from magline.core.plugins import Plugins
    from magline.core.sequencer.context import RunContext
    from magline.core.station.schema import Station


class CurrentSourceError(StationFault):
    """The current source failed or cannot draw what was asked: the unit was not judged (an ERROR)."""


@runtime_checkable
class CurrentSource(Protocol):
    """See :func:`magline.core.hookspecs.magline_register_current_sources`."""

    name: str

    def start(self, run: RunContext) -> None:
        """Ready for this unit: connected, drawing nothing yet (a motor test proves the props are off)."""

    def set_level(self, fraction: float) -> None:
        """Draw ``fraction`` (0 … 1) of the top: a load ``fraction · current_max_a``, a motor test that
        fraction of its throttle; 0 draws nothing."""

    def measured_current_a(self) -> float | None:
        """The current it measures itself now (A); None when it has no measurement of its own."""

    def stop(self) -> None:
        """Draw nothing (input off, motors stopped): called after every sweep, also after errors."""

    def close(self) -> None:
        """End of the batch: release the instrument."""


def open_current_source(station: Station, station_dir: Path, plugins: Plugins) -> CurrentSource:
    """The station's current source, from its ``current_source`` entry; a StationFault naming the
    cause when there is none or its plugin is not loaded."""
    config = station.current_source
    if config is None:
        raise CurrentSourceError("the product measures its current interference but the station names no "
                                 "current_source (electronic-load or motor-test)")
    factory = plugins.current_sources.get(config.type)
    if factory is None:
        known = ", ".join(sorted(plugins.current_sources)) or "none"
        raise CurrentSourceError(f"no current source named {config.type!r} is loaded (loaded: {known})")
    options: Any = plugins.options("current source", config.type, config.options, "current_source.options",
                                   station_dir)
    return factory(config, station_dir, options)
