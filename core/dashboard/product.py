"""What no anchor shows, per product: the distribution of each compass's mounting error, time skew,
current interference and predicted heading error over the latest units, and the firmware versions they
ran — where a design or a supplier change shows before the field returns do.

Why per compass: a GPS mast's compass and the board's differ by design; pooled, a shift in one hides in
the other's spread.
"""

from __future__ import annotations

import html
import json
from collections import Counter, defaultdict
from typing import TYPE_CHECKING, Any

from sqlalchemy import select

from magline.core.measurements import CATALOGUE, base_name
from magline.core.results.tables import measurements, runs

if TYPE_CHECKING:
    from sqlalchemy import Connection

LATEST = 5000  # units a product's distributions are drawn over
SHOWN = ("mounting_error_deg", "time_skew_ms", "interference_pct_at_max", "direction_sigma_deg")


def product_figures(conn: Connection, part: str) -> dict[str, Any]:
    """Per shown measurement: compass → values over the part's latest judged units; and the firmware
    versions those units ran, with how many and when first and last seen."""
    latest = select(runs.c.id).where((runs.c.part == part) & runs.c.verdict.in_(("pass", "fail"))) \
        .order_by(runs.c.id.desc()).limit(LATEST).subquery()
    chosen = measurements.c.run_id.in_(select(latest.c.id)) & measurements.c.value.is_not(None)
    rows = conn.execute(select(measurements.c.name, measurements.c.value).where(chosen)).all()
    values: dict[str, dict[str, list[float]]] = {name: defaultdict(list) for name in SHOWN}
    for name, value in rows:
        base = base_name(name)
        if base in values:
            compass = name[: len(name) - len(base)].rstrip(".") or "mag1"
            values[base][compass].append(float(value))
    firmware: Counter[str] = Counter()
    seen: dict[str, list[str]] = {}
    units = select(runs.c.unit_info, runs.c.started).where(runs.c.id.in_(select(latest.c.id)))
    for info, started in conn.execute(units):
        version = str((json.loads(info) if info else {}).get("firmware") or "unknown")
        firmware[version] += 1
        first_last = seen.setdefault(version, [started, started])
        first_last[0], first_last[1] = min(first_last[0], started), max(first_last[1], started)
    return {"values": values, "firmware": [(v, n, *seen[v]) for v, n in firmware.most_common()]}


def product_sections(part: str, figures: dict[str, Any]) -> list[str]:
    """The page's sections: a histogram per measurement (a trace per compass), then the firmware table."""
    from magline.core.reports.page import figure_html, plain_layout, table, typed_array

    sections = [f"<h1>Design and supply — {html.escape(part)}</h1><p class=note>each compass's distribution over "
                f"the latest {LATEST:,} judged units at most</p>"]
    for name in SHOWN:
        per_compass = figures["values"][name]
        meaning = CATALOGUE.get(name, ("", name))[1]
        if not per_compass:
            sections.append(f"<h2>{html.escape(name)}</h2><p class=note>not measured on this product</p>")
            continue
        layout = {**plain_layout(), "barmode": "overlay", "height": 280, "title": {"text": f"{name}: {meaning}"},
                  "margin": {"l": 50, "r": 20, "t": 30, "b": 40},
                  "xaxis": {"title": {"text": CATALOGUE.get(name, ("",))[0]}}}
        fig = {"data": [{"type": "histogram", "x": typed_array(v), "name": f"{c} ({len(v)})", "opacity": 0.6}
                        for c, v in sorted(per_compass.items())], "layout": layout}
        sections.append(f"<h2>{html.escape(name)}</h2>"
                        f"<div class=product-figure>{figure_html(fig, f'hist-{name}')}</div>")
    sections.append("<h2>Firmware versions</h2>" + table(("firmware", "units", "first seen", "last seen"),
                                                          figures["firmware"], numeric=(1,)))
    return sections
