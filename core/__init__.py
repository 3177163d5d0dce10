"""magline core: sequencer, hook specifications, station files, fit and results.

Installed as ``magline.core``; plugins live in ``magline.plugins``.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("magline")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0+unknown"
