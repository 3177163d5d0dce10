"""The ``fixed`` field source: a magnitude written in the station file.

For cells whose field was surveyed once (or for the mock station); the World Magnetic Model and
a live fluxgate reference are separate sources.
"""

from __future__ import annotations

from typing import Any

from magline.core.plugins import hookimpl


class FixedField:
    def __init__(self, field_ut: float) -> None:
        if not (1.0 <= field_ut <= 1000.0):
            raise ValueError(f"field_source.options.field_ut must be between 1 and 1000 µT, got {field_ut}")
        self.field_ut = float(field_ut)

    def reference_field_ut(self) -> float:
        return self.field_ut


def _factory(station: Any) -> FixedField:
    options = station.field_source.options
    if "field_ut" not in options:
        raise ValueError("field_source.options.field_ut is required for the fixed field source")
    return FixedField(options["field_ut"])


@hookimpl
def magline_register_field_sources(register):
    register("fixed", _factory)
