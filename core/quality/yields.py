"""First-pass yield, retry rate and the causes of refusals, per station, operator and part.

Definitions (what a quality engineer expects, and what keeps a station fault out of the yield):

* **judged** runs are PASS or FAIL; ERROR, ABORTED and INCOMPLETE runs are the station's, not the
  unit's, and are counted apart;
* **first-pass yield** = first runs of a serial that passed / first runs of a serial that were
  judged (a re-test does not improve it);
* **retry rate** = judged runs that needed more than one acquisition attempt / judged runs;
* **causes ranked**: why acquisition attempts were refused (the reason's kind, numbers removed so
  that "coverage 41% below the target 60%" and "coverage 37% …" count together) and which
  measurements failed units.
"""

from __future__ import annotations

import re
from collections import Counter
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from magline.core.results.series import RunSeries


JUDGED = ("pass", "fail")
NUMBER = re.compile(r"[-+]?\d+(\.\d+)?")


@dataclass(frozen=True)
class YieldRow:
    group: str
    runs: int
    judged: int
    station_faults: int  # error / aborted / incomplete: not the unit's
    first_runs: int  # judged first runs of a serial
    first_pass: int
    retried: int

    @property
    def fpy(self) -> float | None:
        return self.first_pass / self.first_runs if self.first_runs else None

    @property
    def retry_rate(self) -> float | None:
        return self.retried / self.judged if self.judged else None


def yields(series: RunSeries, by: str) -> list[YieldRow]:
    """One row per value of ``by`` (``station_id``, ``operator`` or ``part``), largest first."""
    groups: dict[str, list[int]] = {}
    for i, run in enumerate(series.runs):
        groups.setdefault(str(run.get(by) or "—"), []).append(i)
    rows = []
    for group, members in groups.items():
        judged = [i for i in members if series.runs[i]["verdict"] in JUDGED]
        first = [i for i in judged if not series.runs[i].get("earlier_runs")]
        attempts = series.attempts if series.attempts is not None else None
        rows.append(YieldRow(
            group=group, runs=len(members), judged=len(judged), station_faults=len(members) - len(judged),
            first_runs=len(first), first_pass=sum(series.runs[i]["verdict"] == "pass" for i in first),
            retried=sum(int(attempts[i] > 1) for i in judged) if attempts is not None else 0))
    return sorted(rows, key=lambda r: (-r.runs, r.group))


def cause_kind(reason: str) -> str:
    """A refusal's kind: the part before ``:``, numbers replaced, so that like counts with like."""
    head = reason.split(":", 1)[0].strip()
    return NUMBER.sub("N", head)


def kind_in_numbers(kind: str, reasons: list[str]) -> str:
    """A kind's words with each of its numbers given as the range its refusals held ("coverage 10–35%
    below the target 60%"): the ranking groups like with like, and a reader still sees the figures."""
    seen: list[list[float]] = []
    texts: list[list[str]] = []
    for reason in reasons:
        head = reason.split(":", 1)[0].strip()
        for k, match in enumerate(NUMBER.finditer(head)):
            if k == len(seen):
                seen.append([])
                texts.append([])
            seen[k].append(float(match.group()))
            texts[k].append(match.group())
    slots = iter(range(len(seen)))

    def span(_: re.Match) -> str:
        k = next(slots)
        low, high = min(seen[k]), max(seen[k])
        at = {float(t): t for t in texts[k]}
        return at[low] if low == high else f"{at[low]}–{at[high]}"

    return NUMBER.sub(span, reasons[0].split(":", 1)[0].strip()) if seen else kind


def ranked_causes(series: RunSeries) -> tuple[list[tuple[str, int]], list[tuple[str, int]]]:
    """(refusal kinds of acquisition attempts with the range of their figures, failing measurements),
    each most frequent first."""
    by_kind: dict[str, list[str]] = {}
    for per_run in series.refusals:
        for reason in per_run:
            by_kind.setdefault(cause_kind(reason), []).append(reason)
    refusals = sorted(((kind_in_numbers(kind, reasons), len(reasons)) for kind, reasons in by_kind.items()),
                      key=lambda row: -row[1])
    failed = Counter(name for per_run in series.failed for name in per_run)
    return refusals, failed.most_common()
