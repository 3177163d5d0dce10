"""Two ``results`` stores that would write one file or one server: each unit would be recorded twice there.

Why it is an error, not a style point: a store's history, yield, Cpk and 3σ flags count the runs it holds,
so a unit recorded twice in one store counts twice in every figure read from it (and two ``sql`` outboxes in
one file forward each other's copies).  A copy line left unchanged, or two ``sql`` stores both left on the
default outbox, is the usual cause; ``magline check`` says it at the second store's line.
"""

from __future__ import annotations

import os
from pathlib import Path

from magline.core.station.loader import dotted, line_of

# The built-in sinks' own keys that name where a store writes: (sink, key, default, what it is).
WRITES = (("sqlite", "path", "magline-results.sqlite", "SQLite file"),
          ("sql", "outbox", "magline-outbox.sqlite", "SQLite file"),
          ("sql", "url_env", None, "server"))


def results_entries(data: dict) -> list[tuple[tuple, object]]:
    """Each ``results`` entry of a station file's data with its key path: one store (a mapping) or a list."""
    stores = data.get("results")
    if isinstance(stores, dict):
        return [(("results",), stores)]
    return [(("results", i), entry) for i, entry in enumerate(stores)] if isinstance(stores, list) else []


def shared_store_problems(data: dict, text: str, name: str) -> list[str]:
    """One line per store that writes where an earlier store of the same station already writes."""
    entries = results_entries(data)
    here = Path(name).parent
    taken: dict[tuple[str, str], tuple] = {}  # (kind, where it writes) → the first store's key path
    out: list[str] = []
    for where, entry in entries:
        if not isinstance(entry, dict):
            continue
        sink = entry.get("sink", "sqlite")
        for kind_sink, key, default, kind in WRITES:
            value = entry.get(key, default)
            if sink != kind_sink or not isinstance(value, str) or not value:
                continue
            target = value if kind == "server" else os.path.normpath(here / Path(value).expanduser())
            first = taken.setdefault((kind, target), (*where, key))
            if first != (*where, key):
                at = (*where, key) if key in entry else where
                said = f"the environment variable {value}" if kind == "server" else value
                out.append(f"{name}:{line_of(text, at)}: {dotted(at)}: {said} is {dotted(first)}'s {kind} too: "
                           f"every unit would be recorded twice in it (its yield and statistics counting each unit "
                           f"twice); give each store a {kind} of its own")
    return out
