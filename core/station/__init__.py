"""Station files: one YAML file per line/station, validated before anything runs."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from magline.core.station.checks import station_problems
from magline.core.station.loader import StationError, load_station_text, read_station_text
from magline.core.station.schema import Limit, Product, Station


def load_station(path: str | Path, plugins: Any = None) -> Station:
    """The validated station.  With ``plugins`` (:func:`magline.core.plugins.load_plugins`), also
    what only the plugins know — backend, sink, source and motion names and their options — every
    problem in one :class:`StationError`, as ``magline check`` reports them."""
    if plugins is None:
        return load_station_text(read_station_text(path), str(path))  # magline's own measurements only
    station, problems = station_problems(read_station_text(path), str(path), plugins)
    if problems or station is None:
        raise StationError(problems)
    return station


__all__ = ["Limit", "Product", "Station", "StationError", "load_station", "load_station_text"]
