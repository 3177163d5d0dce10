"""What a serial number may be, checked before a record exists.

Why: a record that names the wrong unit is worse than none.  A scanner's trailing space, a pasted
newline or tab, a path separator or a 300-character paste would be stored verbatim — then
``history SN-1`` finds nothing, the verdict panel splits, a report's file name breaks.  So a serial
is trimmed, and refused with the rule said when it is empty, holds a control character or a path
separator, is longer than the product allows, or does not match the product's ``serial_pattern``.
``magline run``, the station screen and slot loads all go through :func:`clean_serial`.
"""

from __future__ import annotations

import re
import unicodedata
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from magline.core.station.schema import Product

DEFAULT_MAX_LENGTH = 64
FORBIDDEN = "/\\"


class SerialRefused(ValueError):
    """The serial breaks a rule; the message says which, in the operator's words."""


def clean_serial(raw: str, product: Product | None = None) -> str:
    """The serial as it is stored (surrounding spaces removed), or :class:`SerialRefused`."""
    serial = (raw or "").strip()
    if not serial:
        raise SerialRefused("no serial number: scan or type the unit's serial")
    bad = next((c for c in serial if unicodedata.category(c).startswith("C") or c in FORBIDDEN), None)
    if bad is not None:
        name = unicodedata.name(bad, f"U+{ord(bad):04X}") if not unicodedata.category(bad).startswith("C") \
            else f"control character U+{ord(bad):04X}"
        raise SerialRefused(f"serial {serial!r} holds {name}: a serial is letters, digits and punctuation "
                            f"other than {' and '.join(FORBIDDEN)} — scan it again")
    limit = product.serial_max_length if product is not None else DEFAULT_MAX_LENGTH
    if len(serial) > limit:
        raise SerialRefused(f"serial of {len(serial)} characters ({serial[:16]}…): at most {limit} are allowed "
                            "— scan the unit's label, not a pasted text")
    pattern = product.serial_pattern if product is not None else None
    if pattern is not None and re.fullmatch(pattern, serial) is None:
        raise SerialRefused(f"serial {serial!r} does not match this part's pattern {pattern} — is it the right "
                            "unit or the right part?")
    return serial
