"""A turntable's cradle drawn for the operator: the tilt asked for, as a side view (the pitch: where the
nose points) and a view from behind (the roll: which side is down), in text for the console and as SVG
for the station screen.  Why two views: one picture of a 3-D tilt reads ambiguously at a glance; a side
and a rear view are what a fixture's work instruction shows."""

from __future__ import annotations

import math

_SIDE_ARROWS = ((-67.5, "↓"), (-22.5, "↘"), (22.5, "→"), (67.5, "↗"), (181.0, "↑"))
_REAR = {0: "─", 45: "╲", -45: "╱", 90: "│", -90: "│", 135: "╱", -135: "╲", 180: "─"}


def cradle_text(pitch_deg: float, roll_deg: float) -> str:
    """``side ↘ · rear ╲`` — the nose's direction seen from the side, the cradle's line seen from behind
    (``▼`` marks upside down)."""
    arrow = next(a for limit, a in _SIDE_ARROWS if pitch_deg < limit)
    roll = int(45 * round((((roll_deg + 180.0) % 360.0) - 180.0) / 45.0))
    roll = 180 if roll == -180 else roll
    rear = _REAR[roll] + (" ▼" if abs(roll) > 90 else "")
    return f"side {arrow} · rear {rear}"


def _bar(cx: float, cy: float, angle_deg: float, length: float, nose: bool) -> str:
    """A cradle's bar turned by ``angle_deg`` (SVG's y down: positive turns clockwise), with a nose mark."""
    a = math.radians(angle_deg)
    dx, dy = math.cos(a) * length / 2, math.sin(a) * length / 2
    bar = (f'<line x1="{cx - dx:.1f}" y1="{cy - dy:.1f}" x2="{cx + dx:.1f}" y2="{cy + dy:.1f}" '
           'stroke="currentColor" stroke-width="10" stroke-linecap="round"/>')
    if nose:
        bar += f'<circle cx="{cx + dx:.1f}" cy="{cy + dy:.1f}" r="9" fill="#e0a000"/>'
    return bar


def cradle_svg(pitch_deg: float, roll_deg: float, words: str) -> str:
    """Two views side by side on a turntable's disc: from the side (the nose a yellow dot, pointing down
    for nose down) and from behind (the right side down for a positive roll).  Self-contained SVG."""
    side = _bar(70, 70, -pitch_deg, 100, nose=True)  # nose up (positive pitch) turns the bar up: −angle in SVG
    rear = _bar(210, 70, roll_deg, 100, nose=False)  # right side down (positive roll) lowers the right end
    upside = '<text x="210" y="40" text-anchor="middle" font-size="16">upside down</text>' \
        if abs(((roll_deg + 180.0) % 360.0) - 180.0) > 90 else ""
    table = ('<ellipse cx="70" cy="128" rx="55" ry="8" fill="none" stroke="currentColor" stroke-width="3"/>'
             '<ellipse cx="210" cy="128" rx="55" ry="8" fill="none" stroke="currentColor" stroke-width="3"/>')
    labels = ('<text x="70" y="156" text-anchor="middle" font-size="14">side</text>'
              '<text x="210" y="156" text-anchor="middle" font-size="14">from behind</text>')
    return (f'<svg class="cradle" viewBox="0 0 280 165" role="img" aria-label="cradle: {words}" '
            f'xmlns="http://www.w3.org/2000/svg">{table}{side}{rear}{upside}{labels}</svg>')
