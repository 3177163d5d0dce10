"""Numbers as an operator reads them: rounded to what matters, with their unit.

Why one module: the console, the verdict panel, phase logs and ``magline history`` all show
values; none may show 0.38549133410640546 or 29.6988 s.
"""

from __future__ import annotations

import math
from typing import Any


def fmt(value: float | None, unit: str = "", digits: int = 4) -> str:
    """``value`` to ``digits`` significant digits (no exponent for everyday magnitudes), then the unit."""
    if value is None:
        return "—"
    if isinstance(value, float) and not math.isfinite(value):
        text = str(value)
    else:
        text = f"{float(value):.{digits}g}"
        if "e" in text and 1e-4 <= abs(value) < 1e7:
            text = f"{float(value):.{max(digits - 1 - math.floor(math.log10(abs(value))), 0)}f}"
    return f"{text} {unit}".rstrip() if unit and unit not in ("%", "°") else f"{text}{unit}"


FLOAT32_RULE = "parameters as the firmware holds them: single precision (float32), 7 significant digits"


def param_text(value: float | None) -> str:
    """A parameter's value as the firmware holds it: the shortest decimal that is the same float32.  Why:
    a value written as 0.95090135 and echoed as the float32 nearest it read "0.9509014" beside "0.9509013"
    at 7 digits — two values where the firmware holds one, which an auditor queries.  Whole numbers (INAV's
    integer settings, an orientation) stay whole."""
    if value is None:
        return "—"
    if float(value).is_integer():
        return str(int(value))
    import numpy as np

    return np.format_float_positional(np.float32(value), unique=True, trim="-")


def percent(fraction: float | None) -> str:
    """0.6234 → ``62%``; None (no base to divide by) → ``—``."""
    return "—" if fraction is None else f"{fraction:.0%}"


def seconds(value: float) -> str:
    """A duration: ``0.42 s``, ``3.1 s``, ``30 s``."""
    if value < 1:
        return f"{value:.2f} s"
    if value < 10:
        return f"{value:.1f} s"
    return f"{value:.0f} s"


def stop_line(reason: str, after_s: float, readings: int, moved: bool = True) -> str:
    """How the operator is told the tumble ended: "determined after 6 s — stop moving the unit".

    ``moved``: the unit is turned (by hand or fixture); a unit standing still in a coil is not told
    to stop moving, and its schedule is not called a tumble."""
    if reason == "determined":
        return f"determined after {after_s:.0f} s ({readings} readings)" + (" — stop moving the unit" if moved else "")
    if reason == "samples" and not moved:
        return f"coil schedule complete: {readings} readings in {after_s:.0f} s"
    if reason == "stalled":
        return f"stalled after {after_s:.0f} s ({readings} readings): not reaching new directions"
    if reason == "timeout":
        return f"time up after {after_s:.0f} s ({readings} readings)"
    if reason == "samples":
        return f"tumble complete: {readings} readings in {after_s:.0f} s"
    return f"the stream ended after {readings} readings"


def for_terminal(message: str, stream: Any) -> str:
    """``message`` wrapped at word boundaries to the width of the terminal ``stream`` is (a terminal wraps a
    long line wherever its edge falls, mid-word); unchanged when ``stream`` is a pipe or a file, where a
    log line stays one line for whoever greps it."""
    isatty = getattr(stream, "isatty", None)
    if not (callable(isatty) and isatty()):
        return message
    import shutil
    import textwrap

    width = shutil.get_terminal_size().columns
    return "\n".join(textwrap.fill(line, width, break_long_words=False, break_on_hyphens=False) or line
                     for line in message.splitlines())
