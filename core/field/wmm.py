"""The ``wmm`` field source: the World Magnetic Model at the station's place and date.

Computed with NOAA's ``wmm-calculator`` package (WMM2025 ships inside it, works offline).  The
station's ``location.altitude_m`` is read as height above mean sea level (what a site survey
gives).  A date outside the model's validity warns and uses the nearest valid date: the field
changes by ~0.1 %/year, far less than a fit's tolerance, but the station should get a newer model.
Options (:mod:`.options`): ``date`` (ISO, default today), ``reference`` (a fluxgate, see :mod:`.reference`).
"""

from __future__ import annotations

import datetime as dt
import math
import warnings
from typing import TYPE_CHECKING, Any

from magline.core.field.checked import CheckedField
from magline.core.plugins import hookimpl

if TYPE_CHECKING:
    from magline.core.field.options import WmmOptions

NT_PER_UT = 1000.0


def decimal_year(day: dt.date) -> float:
    start = dt.date(day.year, 1, 1)
    length = (dt.date(day.year + 1, 1, 1) - start).days
    return day.year + (day - start).days / length


def wmm_field_nt(lat_deg: float, lon_deg: float, alt_m: float, day: dt.date, above: str = "msl") -> dict[str, float]:
    """North, east, down and total field (nT) from WMM; warns and clamps outside the model's validity."""
    from wmm import wmm_calc

    model = wmm_calc()
    when = decimal_year(day)
    try:
        model.setup_time(dyear=when)
    except ValueError as exc:
        valid_from, valid_to = 2024.87, 2029.999  # what the shipped WMM2025 accepts
        clamped = min(max(when, valid_from), valid_to)
        warnings.warn(f"{day.isoformat()} is outside the World Magnetic Model's validity ({exc}); "
                      f"using decimal year {clamped:.3f} — update wmm-calculator", stacklevel=2)
        model.setup_time(dyear=clamped)
    model.setup_env(lat_deg, lon_deg, alt_m, unit="m", msl=(above == "msl"))
    values = model.get_all()
    return {k: float(values[k][0]) for k in ("x", "y", "z", "f")}


class WmmField(CheckedField):
    def __init__(self, station: Any, options: WmmOptions) -> None:
        loc = station.station.location
        self.day = options.date or dt.date.today()
        self.components_nt = c = wmm_field_nt(loc.latitude_deg, loc.longitude_deg, loc.altitude_m, self.day)
        super().__init__(c["f"] / NT_PER_UT, options.reference, f"World Magnetic Model ({self.day.isoformat()})",
                         inclination_deg=math.degrees(math.atan2(c["z"], math.hypot(c["x"], c["y"]))))


@hookimpl
def magline_register_field_sources(register):
    register("wmm", WmmField, options="magline.core.field.options:WmmOptions")
