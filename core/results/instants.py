"""``--since`` / ``--until`` as instants, not text.

Why: runs store their start as UTC ISO text (``2026-11-24T20:53:00.123+00:00``).  Compared as text
with what a person types, ``2026-11-24 20:53`` (a space sorts before "T"), ``…T21:53+01:00`` (the same
instant in another zone) and ``yesterday`` each selected other runs or none, silently.  Here every
spelling of an instant is parsed, turned into UTC and written in the stored format, so the store
compares like with like; what does not parse is refused with the forms that do.

A time without an offset is the local time of the computer magline runs on (what an operator means
by "20:53"); ``Z`` or ``+01:00`` say otherwise.
"""

from __future__ import annotations

import argparse
import re
from datetime import UTC, datetime, timedelta

FORMS = ("an ISO 8601 time (2026-11-24T20:53, 2026-11-24 20:53, 2026-11-24T20:53Z, 2026-11-24T21:53+01:00)",
         "a date (2026-11-24: its local midnight; as --until, the end of that day)", "today, yesterday, now",
         "a time ago: 8h, -8h, 30m, 7d, 2w")
_AGO = re.compile(r"^-?(\d+(?:\.\d+)?)\s*([mhdw])$")
_UNITS = {"m": "minutes", "h": "hours", "d": "days", "w": "weeks"}


def parse_instant(text: str, now: datetime | None = None) -> datetime:
    """An aware UTC datetime for ``text``; ValueError naming the accepted forms when it is none."""
    now = now or datetime.now(UTC)
    word = text.strip().lower()
    local_midnight = now.astimezone().replace(hour=0, minute=0, second=0, microsecond=0)
    if word == "now":
        return now.astimezone(UTC)
    if word == "today":
        return local_midnight.astimezone(UTC)
    if word == "yesterday":
        return (local_midnight - timedelta(days=1)).astimezone(UTC)
    if match := _AGO.match(word):
        return (now - timedelta(**{_UNITS[match.group(2)]: float(match.group(1))})).astimezone(UTC)
    try:
        when = datetime.fromisoformat(text.strip())
    except ValueError:
        raise ValueError(f"{text!r} is not a time: give {'; '.join(FORMS)}") from None
    if when.tzinfo is None:
        when = when.astimezone()  # local time of this computer
    return when.astimezone(UTC)


def stored_form(when: datetime) -> str:
    """The instant as runs store their start (UTC, milliseconds, ``+00:00``): text order = time order."""
    return when.astimezone(UTC).isoformat(timespec="milliseconds")


_DATE = re.compile(r"^\d{4}-\d{2}-\d{2}$")


def until_argument(text: str) -> str:
    """argparse ``type=`` for ``--until``: a bare date includes that day (the window ends at the next
    local midnight) — what "until the 27th" means to a person; any other form is the instant it names."""
    if _DATE.match(text.strip()):
        try:
            day = datetime.fromisoformat(text.strip()).astimezone()
        except ValueError as exc:
            raise argparse.ArgumentTypeError(f"{text!r} is not a date: {exc}") from None
        return stored_form(day + timedelta(days=1))
    return instant_argument(text)


def instant_argument(text: str) -> str:
    """argparse ``type=`` for ``--since`` / ``--until``: a bad time is a usage error (exit 2)."""
    try:
        return stored_form(parse_instant(text))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
