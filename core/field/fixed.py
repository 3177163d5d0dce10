"""The ``fixed`` field source: a magnitude written in the station file.

For cells whose field was surveyed once (or for the mock station); optionally checked against a
live fluxgate (``options.reference``, see :mod:`.reference`).  ``inclination_deg`` (the surveyed dip,
positive down) lets the mounting check judge the inclination each magnetometer sees.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from magline.core.field.checked import CheckedField
from magline.core.plugins import hookimpl

if TYPE_CHECKING:
    from magline.core.field.options import FixedFieldOptions, ReferenceOptions


class FixedField(CheckedField):
    def __init__(self, field_ut: float, reference: ReferenceOptions | None = None,
                 inclination_deg: float | None = None) -> None:
        super().__init__(field_ut, reference, "surveyed field", inclination_deg)


def _factory(station: Any, options: FixedFieldOptions) -> FixedField:
    return FixedField(options.field_ut, options.reference, options.inclination_deg)


@hookimpl
def magline_register_field_sources(register):
    register("fixed", _factory, options="magline.core.field.options:FixedFieldOptions")
