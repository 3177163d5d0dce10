"""magline core: sequencer, hook specifications, station files, fit and results.

Installed as ``magline.core``; plugins live in ``magline.plugins``.
"""


def __getattr__(name: str) -> str:
    """``__version__`` on first use (PEP 562): reading the installed distribution's metadata imports
    ``importlib.metadata``, which every command paid for at its start — and an interrupt then landed in
    it as a traceback (``magline.core.entry``)."""
    if name != "__version__":
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    from importlib.metadata import PackageNotFoundError, version

    try:
        found = version("magline")
    except PackageNotFoundError:  # running from a source tree that is not installed
        found = "0+unknown"
    globals()["__version__"] = found
    return found
