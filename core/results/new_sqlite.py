"""A new SQLite results store, made as a copy of an empty store already at the head revision.

Why: a new file migrated step by step loads and runs every migration script (a third of a second, most of
it alembic reading the scripts).  A process that makes several new stores — a slot station's outboxes, a
test suite — migrates one empty store in memory once and copies its pages into each new file with
SQLite's backup API: the same schema, made by the same migrations, at the cost of a file copy.

The copy is written beside the store under a temporary name and linked to the store's name only if no
file has that name yet (``os.link`` fails rather than replace): two stations making the same store at
once both end with one sound store, and a store that exists is never overwritten.
"""

from __future__ import annotations

import contextlib
import os
import sqlite3
import threading
from pathlib import Path

from sqlalchemy import create_engine
from sqlalchemy.pool import StaticPool

_lock = threading.Lock()
_template: sqlite3.Connection | None = None


def _migrated_template() -> sqlite3.Connection:
    """An in-memory store at the head revision, migrated once per process."""
    global _template
    if _template is None:
        from magline.core.results import schema_version

        memory = sqlite3.connect(":memory:", check_same_thread=False)
        engine = create_engine("sqlite://", creator=lambda: memory, poolclass=StaticPool)
        schema_version.upgrade(engine, "a new store")
        _template = memory
    return _template


def create_at_head(path: Path) -> bool:
    """Make the store ``path`` at the head revision when no file has its name (an empty file counts as
    none); return whether this call made it."""
    if path.exists() and path.stat().st_size > 0:
        return False
    staged = path.with_name(f".{path.name}.{os.getpid()}.{threading.get_ident()}.new")
    try:
        with _lock:
            template = _migrated_template()
            copy = sqlite3.connect(staged)
            try:
                template.backup(copy)
            finally:
                copy.close()
        if path.exists() and path.stat().st_size == 0:
            path.unlink()  # an empty file is a store nobody wrote: replaced, as a migration would fill it
        try:
            os.link(staged, path)
        except FileExistsError:
            return False  # another station made it meanwhile: theirs is the store
        return True
    finally:
        with contextlib.suppress(FileNotFoundError):
            staged.unlink()
