"""A batch of units run by one ``magline run`` invocation: counts, first-pass yield, exit code.

Why yield counts only judged units: ERROR and ABORTED mean the station could not judge the unit
(a cable, a supply, the operator's Ctrl-C); counting them as failures would make the process look
worse than it is and hide the station's own faults.  First-pass yield is the share of judged
serials whose first run in the batch passed.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from magline.core.record import Outcome, RunRecord

JUDGED = (Outcome.PASS, Outcome.FAIL)


@dataclass
class Batch:
    records: list[RunRecord] = field(default_factory=list)

    def add(self, record: RunRecord) -> None:
        self.records.append(record)

    def count(self, outcome: Outcome) -> int:
        return sum(r.verdict is outcome for r in self.records)

    @property
    def units(self) -> int:
        return len(self.records)

    def first_runs(self) -> list[RunRecord]:
        seen: dict[str, RunRecord] = {}
        for r in self.records:
            seen.setdefault(r.serial, r)
        return list(seen.values())

    def first_pass_yield(self) -> tuple[int, int]:
        """(serials that passed on their first run, serials whose first run was judged)."""
        judged = [r for r in self.first_runs() if r.verdict in JUDGED]
        return sum(r.verdict is Outcome.PASS for r in judged), len(judged)

    def exit_code(self) -> int:
        """0 every unit passed, 1 some failed (none errored), 2 an error, an abort or no unit at all."""
        if not self.records or any(r.verdict not in JUDGED for r in self.records):
            return 2
        return 1 if any(r.verdict is Outcome.FAIL for r in self.records) else 0

    def summary(self) -> str:
        """One line that never contradicts itself: the verdicts count runs, the yield counts units, and
        where a unit was tested twice (a re-test in ``--loop``) the line says runs of how many units."""
        passed, judged = self.first_pass_yield()
        counts = ", ".join(f"{self.count(o)} {o}" for o in (Outcome.PASS, Outcome.FAIL, Outcome.ERROR, Outcome.ABORTED)
                           if self.count(o) or o in JUDGED)
        units = len(self.first_runs())
        tested = (f"{self.units} unit{'s' if self.units != 1 else ''}" if units == self.units
                  else f"{self.units} runs of {units} unit{'s' if units != 1 else ''}")
        fpy = f"{passed / judged:.0%} ({passed} of {judged} judged units)" if judged else "— (no unit judged)"
        return f"batch: {tested} — {counts}; first-pass yield {fpy}"
