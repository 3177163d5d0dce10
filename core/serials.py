"""What a serial number may be, checked before a record exists.

Why: a record that names the wrong unit is worse than none.  A scanner's trailing space, a pasted
newline or tab, a path separator or a 300-character paste would be stored verbatim — then
``history SN-1`` finds nothing, the verdict panel splits, a report's file name breaks.  So a serial
is trimmed, and refused with the rule said when it is empty, holds a control character or a path
separator, is longer than the product allows, or does not match the product's ``serial_pattern``.
``magline run``, the station screen and slot loads all go through :func:`clean_serial`.

A product's ``serial_case`` (default ``upper``: labels are printed upper case) folds what was typed,
so ``sn-lower-01`` and ``SN-LOWER-01`` are one unit.  A load of a fixture names each unit once
(:func:`one_serial_per_slot`): the same label scanned for two slots would record two boards under
one serial.  A part the station does not build is refused the same way (:class:`PartRefused`).
"""

from __future__ import annotations

import re
import unicodedata
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from magline.core.station.schema import Product

DEFAULT_MAX_LENGTH = 64
FORBIDDEN = "/\\"


class Refused(ValueError):
    """A unit the station will not start: nothing is recorded; the message says the rule and what to do.
    ``slot``: the slot of a load whose label is to be scanned again, where the refusal names one."""

    slot: str | None = None


class SerialRefused(Refused):
    """The serial breaks a rule; the message says which, in the operator's words."""


class PartRefused(Refused):
    """A part number the station does not build."""


def known_part(part: str, parts: list[str], station_id: str) -> str:
    """``part`` when the station builds it, else :class:`PartRefused` listing the parts it does."""
    if part not in parts:
        import difflib

        close = difflib.get_close_matches(part, parts, n=1, cutoff=0.6)
        hint = f" (did you mean {close[0]}?)" if close else ""
        raise PartRefused(f"part {part!r} is not built on station {station_id}{hint}: its parts are "
                          f"{', '.join(parts)} — choose one of them")
    return part


def one_serial_per_slot(load: dict[str, str]) -> None:
    """Refuse a load (slot id → cleaned serial, in slot order) that names one serial for two slots,
    naming both and the slot whose label to scan again."""
    first: dict[str, str] = {}
    for slot, serial in load.items():
        if not serial:
            continue
        if serial in first:
            refused = SerialRefused(f"{serial} is scanned for slots {first[serial]} and {slot}: one serial is one "
                                    f"unit — scan {slot}'s own label")
            refused.slot = slot
            raise refused
        first[serial] = slot


def clean_serial(raw: str, product: Product | None = None) -> str:
    """The serial as it is stored (surrounding spaces removed, upper-cased unless the product keeps its
    case), or :class:`SerialRefused`."""
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
    if product is None or product.serial_case == "upper":
        serial = serial.upper()
    pattern = product.serial_pattern if product is not None else None
    if pattern is not None and re.fullmatch(pattern, serial) is None:
        raise SerialRefused(f"serial {serial!r} does not match this part's pattern {pattern} — is it the right "
                            "unit or the right part?")
    return serial
