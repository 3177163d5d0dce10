"""The mounting checks as a plugin (entry point ``mounting``): the hook is declared here and its work,
:mod:`magline.core.mounting.checks`, imported on the first unit judged.

Why a module of its own: every ``magline`` command loads every plugin, and the checks pull in the
mounting's estimate, pymavlink's orientation tables and the station schema — a twentieth of a second
that ``magline --help`` or ``magline check`` would spend for nothing.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from magline.core.plugins import hookimpl

if TYPE_CHECKING:
    from magline.core.fit import FitResult
    from magline.core.measurements import Measurement
    from magline.core.sequencer.context import RunContext


@hookimpl
def magline_validate_unit(run: RunContext, fits: dict[int, FitResult]) -> list[Measurement]:
    from magline.core.mounting.checks import validate_unit

    return validate_unit(run, fits)
