"""A path a plugin's options take from a station file, read as the station file's own paths are.

Why: a station file names its results store and report folder relative to itself, so a station works from
whatever folder the line's launcher starts it in.  A plugin's option that names a file (the mock DUT's
non-volatile storage, a calibration table) should read the same way, or two stations run from one folder
share the file and each reads what the other wrote.  Core validates every plugin's options with the station
file's folder in pydantic's validation context (``{"station_dir": Path}``); a field declared
:data:`StationPath` resolves a relative value against it.  Without a station folder (a plugin's own tests
building its options model directly) the value stays as written.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from pydantic import AfterValidator, ValidationInfo

STATION_DIR = "station_dir"  # the key core puts the station file's folder under in the validation context


def _against_station(value: str, info: ValidationInfo) -> str:
    station_dir = (info.context or {}).get(STATION_DIR)
    if station_dir is None:
        return value
    path = Path(value).expanduser()
    return str(path if path.is_absolute() else Path(station_dir) / path)


StationPath = Annotated[str, AfterValidator(_against_station)]
"""A file or folder option: absolute as written, relative to the station file's folder otherwise."""
