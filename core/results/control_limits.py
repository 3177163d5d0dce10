"""Frozen control limits in the results store: written by ``magline spc --freeze``, read by every ``spc``.

Why in the results store: the limits belong to the process the store records, and every computer of a
line that reads the store must judge its units against the same limits — a file on one PC would not
be.  Each freeze is a new version (nothing is overwritten: an audit sees which limits judged which
window), with who froze it, when, from which baseline and with which software.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING

from sqlalchemy import func, select

from magline.core.results.tables import control_limits

if TYPE_CHECKING:
    from sqlalchemy import Connection

EVERY_STATION = ""  # the station_id of limits frozen over every station writing to the store


@dataclass(frozen=True)
class FrozenLimits:
    """One measurement's centre line and σ as a baseline established them."""

    measurement: str
    centre: float
    sigma_within: float
    mr_bar: float
    n: int
    baseline: str  # how the baseline was chosen, in words
    first_run: int
    last_run: int
    signals: list[dict] = field(default_factory=list)  # the run rules' signals on the baseline itself
    version: int = 0
    station_id: str = EVERY_STATION
    frozen_by: str = ""
    frozen_at: str = ""
    software_version: str = ""
    # how the baseline was accepted: the serials left out of it, and an unstable one's reason
    acceptance: dict = field(default_factory=dict)

    def words(self) -> str:
        where = f"station {self.station_id}" if self.station_id else "every station"
        return (f"frozen v{self.version} {self.frozen_at[:16]} by {self.frozen_by or '?'} from {self.baseline} "
                f"({where})")


def freeze(conn: Connection, part: str, station_id: str, limits: list[FrozenLimits], by: str, at: str,
           software_version: str) -> int:
    """Store ``limits`` as the next version for ``part`` on ``station_id`` (one version for them all)."""
    newest = conn.execute(select(func.max(control_limits.c.version)).where(
        (control_limits.c.part == part) & (control_limits.c.station_id == station_id))).scalar()
    version = (newest or 0) + 1
    rows = []
    for item in limits:
        row = asdict(item)
        row.update(part=part, station_id=station_id, version=version, frozen_by=by, frozen_at=at,
                   software_version=software_version, signals=json.dumps(item.signals),
                   acceptance=json.dumps(item.acceptance))
        rows.append(row)
    if rows:
        conn.execute(control_limits.insert(), rows)
    return version


def newest(conn: Connection, part: str, station_id: str | None) -> dict[str, FrozenLimits]:
    """The newest frozen limits of ``part``: the station's own where it has any, else those frozen over
    every station; {} when none were frozen (the report then says its limits are provisional)."""
    for where in ([station_id] if station_id else []) + [EVERY_STATION]:
        version = conn.execute(select(func.max(control_limits.c.version)).where(
            (control_limits.c.part == part) & (control_limits.c.station_id == where))).scalar()
        if version is None:
            continue
        rows = conn.execute(select(control_limits).where(
            (control_limits.c.part == part) & (control_limits.c.station_id == where)
            & (control_limits.c.version == version)))
        found = {}
        for r in rows:
            data = dict(r._mapping)
            data.pop("id")
            data.pop("part")
            data["signals"] = json.loads(data["signals"] or "[]")
            data["acceptance"] = json.loads(data.get("acceptance") or "{}")
            found[data["measurement"]] = FrozenLimits(**data)
        return found
    return {}
