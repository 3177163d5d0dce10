"""``magline spc --freeze``: AIAG's Phase I — establish a part's control limits from a baseline of its
judged units, check that the baseline itself was stable, and store the limits, versioned, in the
results store (:mod:`magline.core.results.control_limits`), where every later ``spc`` finds them.

Why frozen: limits computed from the very units they judge can never show that the process moved
while those units were made; a line establishes them once from a stable stretch (≥ 25 units, the
AIAG SPC manual's minimum) and then holds the process to them (Phase II) until an engineer freezes a
new version.  A baseline with rule signals is refused, each signal named with its unit: limits from an
unstable stretch would judge every later unit against a process that was not in control.  The engineer
either leaves the units whose cause is known out (``--exclude SERIAL``) or accepts the baseline as it is
with a reason (``--accept-unstable --reason "…"``); who froze it (``--by``, required) and how it was
accepted are kept with the version.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from magline.core import __version__
from magline.core.measurements import POSSIBLE, base_name
from magline.core.quality.capability import MIN_UNITS, MIN_UNITS_SOURCE
from magline.core.quality.charts import control_limits
from magline.core.quality.spc import SpcReport
from magline.core.record import now_iso
from magline.core.results.control_limits import EVERY_STATION, FrozenLimits, freeze


class BaselineRefused(ValueError):
    """No limits can be frozen from this baseline (too few units, nothing to chart): the sentence says why."""


class BaselineUnstable(BaselineRefused):
    """The baseline's own charts signal: refused unless its units are excluded or it is accepted with a reason."""


@dataclass(frozen=True)
class Acceptance:
    """Who freezes the limits and how the baseline was accepted (kept with the version)."""

    by: str
    excluded: tuple[str, ...] = ()
    accept_unstable: bool = False
    reason: str = ""
    extra: dict = field(default_factory=dict)

    def stored(self) -> dict:
        return {"excluded": list(self.excluded), "accepted_unstable": self.accept_unstable, "reason": self.reason}


@dataclass(frozen=True)
class Frozen:
    version: int
    limits: list[FrozenLimits]

    @property
    def stable(self) -> bool:
        return not any(item.signals for item in self.limits)


def baseline_words(first: int | None, since: str | None, until: str | None) -> str:
    if first is not None:
        return f"the first {first} judged units"
    return f"the judged units from {since or 'the first'} to {until or 'the last'}"


def freeze_baseline(engine: object, report: SpcReport, part: str, station_id: str | None, words: str,
                    accepted: Acceptance) -> Frozen:
    """Store the limits of every chart of ``report`` (built over the baseline's units alone, each point
    in the baseline) as the next version; raise :class:`BaselineRefused` when nothing can be frozen, and
    :class:`BaselineUnstable` when the baseline signals and was not accepted as it is."""
    runs = report.series.runs
    judged = [r for r in runs if r["verdict"] in ("pass", "fail")]
    if len(judged) < MIN_UNITS:
        raise BaselineRefused(f"a baseline needs at least {MIN_UNITS} judged units ({MIN_UNITS_SOURCE}); {words} "
                              f"of part {part} hold {len(judged)}: nothing frozen")
    if not report.measurements:
        raise BaselineRefused(f"no characteristic of part {part} varies over {words}: nothing to freeze "
                              "(check --measurement and the station's limits)")
    limits = []
    for m in report.measurements:
        c = m.chart
        used = [runs[i] for i, inside in zip(c.index, c.in_baseline, strict=True) if inside]
        signalled = [(s.rule, runs[c.index[s.point]]) for s in c.signals]
        limits.append(FrozenLimits(
            measurement=m.name, centre=c.centre, sigma_within=c.sigma, mr_bar=c.mr_bar, n=c.baseline, baseline=words,
            first_run=int(used[0]["id"]), last_run=int(used[-1]["id"]),
            signals=[{"rule": rule, "serial": run["serial"], "run_id": run["id"]} for rule, run in signalled]))
    unstable = [f"{item.measurement}: {s['rule']} at {s['serial']} (run {s['run_id']})"
                for item in limits for s in item.signals]
    if unstable and not accepted.accept_unstable:
        serials = sorted({s["serial"] for item in limits for s in item.signals})
        raise BaselineUnstable(
            f"the baseline of part {part} ({words}) is NOT stable, nothing frozen: " + "; ".join(unstable)
            + f". Find each cause; then leave those units out (--exclude {' --exclude '.join(serials)}) or freeze the "
            "baseline as it is, saying why (--accept-unstable --reason \"…\")")
    who = accepted.by
    limits = [FrozenLimits(**{**vars(item), "acceptance": accepted.stored()}) for item in limits]
    with engine.begin() as conn:  # type: ignore[attr-defined]
        version = freeze(conn, part, station_id or EVERY_STATION, limits, who, now_iso(), __version__)
    stored = [FrozenLimits(**{**vars(item), "version": version, "frozen_by": who,
                              "station_id": station_id or EVERY_STATION}) for item in limits]
    return Frozen(version=version, limits=stored)


def frozen_text(frozen: Frozen, part: str, station_id: str | None) -> str:
    """What the engineer reads after freezing: the version, each limit, and the baseline's stability."""
    where = f"station {station_id}" if station_id else "every station"
    lines = [f"froze limits v{frozen.version} of part {part} ({where}) from {frozen.limits[0].baseline}, "
             f"{len(frozen.limits)} characteristics:"]
    for item in frozen.limits:
        state = "stable" if not item.signals else "NOT STABLE: " + "; ".join(
            f"{s['rule']} at {s['serial']}" for s in item.signals)
        # the limits as every later chart draws them: inside what the measurement can take
        lcl, ucl = control_limits(item.centre, item.sigma_within,
                                  POSSIBLE.get(base_name(item.measurement), (-np.inf, np.inf)))
        lines.append(f"  {item.measurement:<28} n {item.n:>4}  centre {item.centre:.6g}  σ {item.sigma_within:.4g}  "
                     f"LCL {lcl:.6g}  UCL {ucl:.6g}  {state}")
    acceptance = frozen.limits[0].acceptance if frozen.limits else {}
    if acceptance.get("excluded"):
        lines.append(f"left out of the baseline: {', '.join(acceptance['excluded'])}")
    lines.append(f"frozen by {frozen.limits[0].frozen_by}" if frozen.limits else "")
    lines.append("the baseline was stable: every later spc judges units against these limits" if frozen.stable else
                 f"the baseline was NOT stable, accepted as it is by {frozen.limits[0].frozen_by}: "
                 f"{acceptance.get('reason', '')}; these limits judge later units until a new version is frozen")
    return "\n".join(line for line in lines if line)
