"""Names a package offers, imported from their home module the first time they are asked for (PEP 562).

Why: every ``magline`` command loads every plugin, and the packages the plugins import from (the public
face, the fit, the mounting, the sequencer) each pulled in the heaviest of their modules — SciPy's
rotations, the least-squares fit, pymavlink's tables — whether a command used them or not; a command's
start took most of a second before it did anything.
"""

from __future__ import annotations

from collections.abc import Callable
from importlib import import_module


def lazy_names(package: str, homes: dict[str, tuple[str, ...]]) -> tuple[list[str], Callable[[str], object],
                                                                            Callable[[], list[str]]]:
    """``(__all__, __getattr__, __dir__)`` for ``package`` whose names live in ``homes`` (module → names)."""
    module_of = {name: module for module, names in homes.items() for name in names}
    names = sorted(module_of, key=lambda name: (not name.isupper(), name[:1].islower(), name))

    def __getattr__(name: str) -> object:
        module = module_of.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(import_module(module), name)
        setattr(import_module(package), name, value)  # asked once: a plain attribute from then on
        return value

    def __dir__() -> list[str]:
        return list(names)

    return names, __getattr__, __dir__


def warm_imports(*modules: str) -> None:
    """Import ``modules`` on a background thread, now, so that whoever needs them later finds them made.
    Why: a command imports what it uses on first use, and a first use in the middle of a tumble (the running
    fit's SciPy) delayed the stop by the import's time — every unit read on for it.  The import system
    locks per module: a use that comes while one is still being imported waits for it, never sees it half
    made."""
    import threading

    def load() -> None:
        for module in modules:
            import_module(module)

    threading.Thread(target=load, name="magline-warm-imports", daemon=True).start()
