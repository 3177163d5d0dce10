"""The default acquire phase as a plugin (entry point ``tumble_acquisition``): the hook is declared here
and the tumble, :mod:`magline.core.acquisition.tumble`, imported on the first unit.

Why a module of its own: every ``magline`` command loads every plugin, and the tumble pulls in the
running fit, the coverage and the guidance that ``magline --help`` or ``magline check`` never use.

``trylast``: a plugin implementing ``magline_acquire`` replaces it (the Helmholtz coil does).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from magline.core.plugins import hookimpl

if TYPE_CHECKING:
    from magline.core.sequencer.context import Acquisition, RunContext


@hookimpl(trylast=True)
def magline_acquire(run: RunContext, attempt: int) -> Acquisition:
    from magline.core.acquisition.tumble import acquire

    return acquire(run, attempt)
