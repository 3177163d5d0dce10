"""A stored record's unit facts, compasses, mounting and power cycle as a person reads them.

Why one module: ``magline show`` (text) and the unit report (HTML) print the same facts, and both
once printed the stored JSON as it is — Python dicts inside a table cell.  Here each part of the
record becomes rows of words with units; the two outputs only lay the rows out.
"""

from __future__ import annotations

from typing import Any

from magline.core.text import fmt

# a stored key's unit suffix → the unit a person reads (a figure named time_to_heartbeat_s is in s)
UNIT_SUFFIXES = (("_ut", "µT"), ("_pct", "%"), ("_deg", "°"), ("_ms", "ms"), ("_s", "s"), ("_a", "A"),
                 ("_v", "V"), ("_hz", "Hz"))
SHOWN_APART = ("magnetometers", "mounting", "sensors", "selected_sensor", "interference",
               "interference_notes")  # tables of their own


def key_words(key: str) -> tuple[str, str]:
    """(words, unit) of a stored key: ``calibrated_field_sigma_ut`` → ("calibrated field sigma", "µT")."""
    for suffix, unit in UNIT_SUFFIXES:
        if key.endswith(suffix):
            return key[: -len(suffix)].replace("_", " "), unit
    return key.replace("_", " "), ""


def value_words(value: Any, unit: str = "") -> str:
    """Any stored value in words: numbers with their unit, lists joined, mappings as "name value; …"."""
    if value is None or value == "":
        return "—"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int | float):
        if unit == "s" and 0 < abs(value) < 1.0:  # a short time in ms: "0.124 ms", not "0.000124 s"
            return fmt(value * 1000.0, "ms")
        return fmt(value, unit)
    if isinstance(value, dict):
        parts = []
        for k, v in value.items():
            words, inner = key_words(str(k))
            parts.append(f"{words} {value_words(v, inner)}")
        return "; ".join(parts) if parts else "—"
    if isinstance(value, list | tuple):
        return ", ".join(value_words(v, unit) for v in value) if value else "none"
    return str(value)


def unit_facts(unit_info: dict[str, Any] | None) -> list[tuple[str, str]]:
    """The unit's facts (autopilot, firmware, soft-iron model, warm-up …) as (name, words) rows; the
    compasses and their mounting are :func:`compass_rows` and :func:`mounting_rows`."""
    rows = []
    for key, value in (unit_info or {}).items():
        if key in SHOWN_APART:
            continue
        words, unit = key_words(key)
        rows.append((words, value_words(value, unit)))
    return rows


def compass_rows(unit_info: dict[str, Any] | None) -> list[tuple[str, str, str, str]]:
    """(compass, label, device id, orientation) for each magnetometer the run calibrated."""
    rows = []
    for position, sensor in enumerate((unit_info or {}).get("magnetometers") or [], 1):
        where = {True: "external", False: "internal"}.get(sensor.get("external"), "")
        label = " ".join(w for w in (str(sensor.get("label") or "magnetometer"), where and f"({where})") if w)
        rows.append((sensor.get("prefix") or f"mag{position}", label, str(sensor.get("device_id", "—")),
                     value_words(sensor.get("orientation"))))
    return rows


def mounting_rows(unit_info: dict[str, Any] | None) -> list[tuple[str, str, str, str]]:
    """(compass or pair, what was found, how far from it, the inclination seen) per mounting entry."""
    mounting = (unit_info or {}).get("mounting")
    if not isinstance(mounting, dict):
        return [("—", value_words(mounting), "", "")] if mounting else []
    rows = []
    for key, v in mounting.items():
        if not isinstance(v, dict):
            rows.append((key, value_words(v), "", ""))
        elif "found" in v:
            skew = (f"; time skew {fmt(v['skew_ms'], 'ms')} ± {fmt(v.get('skew_sigma_ms'), 'ms')}"
                    if v.get("skew_ms") is not None else "")
            rows.append((key, f"orientation {v['found']} (configured {v['configured']})",
                         f"{v['from_nearest_deg']:.2f}° ± {v['sigma_deg']:.2f}° from it, {v.get('pairs', '—')} "
                         f"paired readings{skew}", f"{v['inclination_deg']:.2f}°"))
        else:
            fitted = f" (relation fitted to {v['used']} of {v['pairs']} paired readings)" if "used" in v else ""
            timing = (f"; relative timing open by ±{v['timing_window_ms']:.1f} ms, taken at "
                      f"{v.get('timing_shift_ms', 0.0):+.2f} ms: timing alone explains up to "
                      f"{v.get('timing_deg', 0.0):.1f}°" if v.get("timing_window_ms") else "")
            rows.append((key, "heading agreement",
                         f"median {v['median_deg']:.2f}°, max {v['max_deg']:.2f}°{fitted}{timing}", ""))
    return rows


def persistence_rows(persistence: dict[str, Any] | None) -> list[tuple[str, str]]:
    """The power cycle as (name, words) rows: how, its figures with units, the sensor, the mismatches."""
    if not persistence:
        return []
    rows = [("power cycle", str(persistence.get("method") or "—"))]
    if persistence.get("store"):
        rows.append(("calibration kept in", str(persistence["store"])))
    for key, value in (persistence.get("figures") or {}).items():
        words, unit = key_words(key)
        rows.append((words, value_words(value, unit)))
    if "sensor_present" in persistence:
        rows.append(("magnetometer after the power cycle", "present" if persistence["sensor_present"] else "MISSING"))
    mismatches = persistence.get("mismatches") or []
    rows.append(("read back", "as written" if not mismatches else "MISMATCH: " + "; ".join(map(str, mismatches))))
    return rows


def _known(compass: dict[str, Any]) -> str:
    """How well a compensated compass's written slope was known, in words (records before it: nothing)."""
    known = compass.get("known_pct")
    return f" (known to ±{known:.1f} % of it)" if isinstance(known, int | float) else ""


def interference_rows(unit_info: dict[str, Any] | None) -> list[tuple[str, str, str, str]]:
    """(compass, field per amp with σ, share of the field at the top current in words, linearity and
    return to zero) per compass swept, then what compensation left after the power cycle; a note where a
    compass could not be compensated."""
    from magline.core.interference.model import zone_words

    found = (unit_info or {}).get("interference")
    if not isinstance(found, dict) or "compasses" not in found:
        return []
    names = {str(device): name for name, _, device, _ in compass_rows(unit_info)}
    top = found.get("current_max_a")
    rows = []
    for device, c in found["compasses"].items():
        per_amp = float(sum(v * v for v in c["per_amp_ut"]) ** 0.5)
        left = (found.get("proof") or {}).get(device)
        rows.append((f"{names.get(device, 'compass')} ({device})",
                     f"{per_amp:.3f} ± {c['per_amp_sigma_ut']:.3f} µT/A",
                     f"{c['pct_at_max']:.1f} % of the field at {top:g} A — {zone_words(c['pct_at_max'])}"
                     + (f"; compensated{_known(c)}: {left['left_pct_at_max']:.2f} % of the field left after the "
                        "power cycle" if left else ""),
                     f"line within {c['linearity_ut']:.2f} µT, back at 0 A within {c['return_ut']:.2f} µT"))
    for note in (unit_info or {}).get("interference_notes") or []:
        rows.append(("note", value_words(note), "", ""))
    return rows
