"""What a capability study is, said before its figures (ISO 22514 asks for it; an auditor reads it first):
the product, the specification's source, the measurement system's reference, who is responsible, the
window asked for, and how many distinct boards stand behind the points.

Why the boards are counted, and how: a line's demo or a gauge study tests one board again and again
under fresh serials; its spread is the station's repeatability, not the process's capability, and a Cpk
of 665 from it is no property of a process.  A board tested again starts from the calibration it was
given: its parameters before the test are the previous test's written values.  So a run whose
parameters before equal an earlier run's written ones is taken as that run's board, and the count of
boards is the count of chains (a board's first test starts from its factory values).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

PLAUSIBLE_INDEX = 10.0  # above it an index carries a note: rarely a property of a process
REPEATABILITY_SHARE = 0.5  # fewer boards than this share of the units: a repeatability study
SIGNIFICANT = 6  # parameters compared to this many significant digits (firmwares echo float32)


@dataclass(frozen=True)
class StudyHeader:
    product: str
    station_file: str
    specification: str  # the limit sets the window's runs were judged against
    reference: str  # the field source the station measures against
    responsible: str
    window: str
    points: int
    units: int  # distinct serials
    boards: int | None  # distinct boards behind them (None: no parameters recorded to tell)

    @property
    def repeatability(self) -> bool:
        return self.boards is not None and self.boards < REPEATABILITY_SHARE * self.units

    def kind(self) -> str:
        if self.repeatability:
            return (f"REPEATABILITY STUDY, not process capability: {self.boards} board(s) behind {self.units} "
                    "units (each test started from the previous test's calibration)")
        return "process capability" + ("" if self.boards is None else f" ({self.boards} distinct boards)")

    def lines(self) -> list[str]:
        return [f"study: {self.kind()}", f"product {self.product} (station file {self.station_file})",
                f"specification: {self.specification}", f"measurement reference: {self.reference}",
                f"responsible: {self.responsible}", f"window: {self.window}; {self.points} runs, {self.units} units"]

    def to_dict(self) -> dict[str, Any]:
        return {"kind": self.kind(), "repeatability": self.repeatability, "product": self.product,
                "station_file": self.station_file, "specification": self.specification, "reference": self.reference,
                "responsible": self.responsible, "window": self.window, "points": self.points, "units": self.units,
                "boards": self.boards}


def _key(values: dict[str, float]) -> frozenset:
    return frozenset((name, float(f"{value:.{SIGNIFICANT}g}")) for name, value in values.items())


def count_boards(params: dict[int, dict[str, dict[str, float]]], run_ids: list[int]) -> int | None:
    """Distinct boards behind ``run_ids`` (oldest first) from each run's parameters by stage ("before",
    "written"); None when no run recorded both."""
    written_by: dict[frozenset, int] = {}
    boards = 0
    told = False
    for run_id in run_ids:
        stages = params.get(run_id, {})
        before, written = stages.get("before"), stages.get("written")
        if not before or not written:
            continue
        told = True
        board = written_by.get(_key(before))
        if board is None:
            boards += 1
            board = boards
        written_by[_key(written)] = board
    return boards if told else None


def plausibility_note(value: float | None) -> str:
    return (f"an index over {PLAUSIBLE_INDEX:g} is rarely a property of a process: check the limits and that the "
            "units are distinct boards") if value is not None and value > PLAUSIBLE_INDEX else ""
