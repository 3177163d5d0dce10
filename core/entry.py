"""The ``magline`` command's entry point: a Ctrl-C at any instant — while the command's modules are still
being imported, or inside a command that does not handle it — ends it with one line and the exit code of
an abort, never a Python traceback.

Why its own module: the console script imports its target before calling it, so an interrupt during
``magline.core.cli``'s imports (half a second of them) reached the user as a traceback; this module
imports nothing heavy before the handler is in place.
"""

from __future__ import annotations

import sys

ABORT_EXIT = 2  # what the README gives for an abort (``magline run``: an error, an abort, no unit tested)


def main() -> int:
    try:
        from magline.core.cli import main as command

        return command()
    except KeyboardInterrupt:
        print("magline: interrupted (Ctrl-C): nothing more was done", file=sys.stderr)
        return ABORT_EXIT


if __name__ == "__main__":
    sys.exit(main())
