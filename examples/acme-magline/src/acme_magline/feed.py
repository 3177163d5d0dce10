"""The plant's feed: one JSON line per finished unit, for the plant's MES, configured in the station file.

A listener, not a results store: it hears ``magline_unit_finished`` once the unit's record is stored by
the station's own store, so a feed that cannot write (a full disk, a share gone) never touches the
verdict — magline catches what it raises and says it on the run (``record.listener_faults``) as a
warning.  (A plugin that must keep the record itself, so that a unit is an ERROR when it cannot, is a
results sink or answers ``magline_record_unit`` instead.)

    plugins:
      acme-feed:
        path: plant/units.jsonl   # relative to the station file
        parts: [ACME-7]           # only these products' units (every product's when left out)
"""

from __future__ import annotations

import json
from pathlib import Path

from magline.plugin import Numeric, hookimpl
from pydantic import BaseModel, ConfigDict

SECTION = "acme-feed"


class FeedOptions(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, defer_build=True)
    path: str
    """The plant's feed file, relative to the station file."""
    parts: list[str] | None = None
    """Only these part numbers' units (none: every unit)."""


@hookimpl
def magline_register_plugin_options(register):
    register(SECTION, FeedOptions)


@hookimpl
def magline_unit_finished(run, record):
    options = run.plugin_options(SECTION)
    if options is None or (options.parts is not None and record.part not in options.parts):
        return  # not configured on this station, or another product's unit
    line = {"serial": record.serial, "part": record.part, "station": record.station_id, "verdict": str(record.verdict),
            "cause": record.cause, "finished": str(record.finished), "limit_hash": record.limit_hash,
            "measurements": {m.name: m.value for m in record.measurements if isinstance(m, Numeric)}}
    path = Path(run.station_dir) / options.path
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("a", encoding="utf-8") as out:
        out.write(json.dumps(line) + "\n")
