"""Station files: one YAML file per line/station, validated before anything runs."""

from magline.core.station.loader import StationError, load_station, load_station_text
from magline.core.station.schema import Limit, Product, Station

__all__ = ["Limit", "Product", "Station", "StationError", "load_station", "load_station_text"]
