"""Guard (datasette style): every hook is documented and called by at least one test."""

from __future__ import annotations

import inspect
from pathlib import Path

from magline.core import hookspecs

HOOKS = [name for name, fn in inspect.getmembers(hookspecs, inspect.isfunction) if name.startswith("magline_")]
TESTS = Path(__file__).parent


def test_there_are_hooks_for_every_lifecycle_phase():
    for phase in ("acquire", "fit", "validate", "persist", "verify_persistence"):
        assert f"magline_{phase}" in HOOKS


def test_every_hook_is_documented():
    for name in HOOKS:
        doc = inspect.getdoc(getattr(hookspecs, name)) or ""
        assert len(doc) > 40, f"{name} needs a docstring saying when it is called and what it returns"


def test_every_hook_is_exercised_by_a_test():
    """Each hook name must appear in a test that implements or calls it."""
    sources = "".join(p.read_text(encoding="utf-8") for p in TESTS.glob("test_*.py") if p.name != Path(__file__).name)
    missing = [h for h in HOOKS if h not in sources]
    assert not missing, f"hooks without a test: {missing}"
