"""The ``operator`` motion: a person turns the unit (or the cradle holding several units).

Nothing to drive: the acquire phase prompts the operator, and a slot station's rounds still line
the slots up so that one tumble serves every unit that needs samples.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from magline.core.plugins import hookimpl

if TYPE_CHECKING:
    from magline.core.station.schema import Station


class OperatorMotion:
    type = "operator"

    def start(self, round: int, slots: list[str]) -> None:
        return None

    def stop(self) -> None:
        return None

    def close(self) -> None:
        return None


def create_operator_motion(station: Station, station_dir: Path, options: object) -> OperatorMotion:
    return OperatorMotion()


@hookimpl
def magline_register_motions(register):
    register("operator", create_operator_motion, options="magline.core.station.no_options:NoOptions")
