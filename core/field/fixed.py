"""The ``fixed`` field source: a magnitude written in the station file.

For cells whose field was surveyed once (or for the mock station); optionally checked against a
live fluxgate (``options.reference``, see :mod:`.reference`).  ``inclination_deg`` (the surveyed dip,
positive down) lets the mounting check judge the inclination each magnetometer sees.
"""

from __future__ import annotations

from typing import Any

from magline.core.field.checked import CheckedField
from magline.core.plugins import hookimpl


class FixedField(CheckedField):
    def __init__(self, field_ut: float, reference: dict[str, Any] | None = None,
                 inclination_deg: float | None = None) -> None:
        if not (1.0 <= field_ut <= 1000.0):
            raise ValueError(f"field_source.options.field_ut must be between 1 and 1000 µT, got {field_ut}")
        if inclination_deg is not None and not -90.0 <= inclination_deg <= 90.0:
            raise ValueError(f"field_source.options.inclination_deg must be between -90 and 90°, got {inclination_deg}")
        super().__init__(field_ut, reference, "surveyed field", inclination_deg)


def _factory(station: Any, options: dict) -> FixedField:
    options = station.field_source.options
    if "field_ut" not in options:
        raise ValueError("field_source.options.field_ut is required for the fixed field source")
    unknown = set(options) - {"field_ut", "reference", "inclination_deg"}
    if unknown:
        raise ValueError(f"field_source.options: unknown option(s) {', '.join(sorted(unknown))} for fixed "
                         "(known: field_ut, inclination_deg, reference)")
    return FixedField(options["field_ut"], options.get("reference"), options.get("inclination_deg"))


@hookimpl
def magline_register_field_sources(register):
    register("fixed", _factory)
