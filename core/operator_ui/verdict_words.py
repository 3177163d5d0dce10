"""A unit's verdict in the operator's words, the same on the station screen and the console: which
verdict is shown (PASS with a flag is REVIEW), what to do with the unit, and for a unit with several
compasses one card per compass naming what failed in it.

Why one module: the screen and the console are two views of one run; the words an operator acts on
must not differ between them.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from magline.core.interference.model import zone_words
from magline.core.measurements import CATALOGUE, DECLARED_MEANINGS, Verdict, base_name, by_sensor, verdicts
from magline.core.text import fmt

if TYPE_CHECKING:
    from magline.core.record import RunRecord


def shown_verdict(record: RunRecord) -> str:
    """The verdict as the operator is shown it: a unit that passed with a measurement flagged (marginal,
    or off the process) is REVIEW; every other verdict as recorded."""
    flagged = any(m.verdict in (Verdict.FAIL, Verdict.REVIEW) for m in verdicts(record.measurements))
    return "review" if str(record.verdict) == "pass" and flagged else str(record.verdict)


def closing_line(record: RunRecord, action: str) -> str:
    """The unit's last line: verdict, serial and what the operator does with the unit
    ("FAIL AP-0003 — put the unit in the reject bin")."""
    shown = shown_verdict(record).upper()
    where = f"slot {record.slot}: " if record.slot else ""
    todo = f" — {action[:1].lower()}{action[1:]}" if action else ""
    return f"{where}{shown} {record.serial}{todo}"


def verdict_items(record: RunRecord, measured: list, owner: bool = True) -> list[dict[str, str]]:
    """The measurements the operator must see: every FAIL and REVIEW, with why a REVIEW was flagged.
    ``owner`` False: their words without the compass or pair they are of (a card titled with it).
    A measurement's note (the parameter that fixes it, the orientation found) is ``detail``: the
    technician's, shown apart in small type — the operator's job is the unit, not its parameters."""
    flags = {f["name"]: f["reason"] for f in record.review}
    return [{"name": m.name, "label": label_of(m.name, owner), "value": fmt(m.value, m.unit),
             "limit": f"[{fmt(m.low)}, {fmt(m.high)}]", "verdict": str(m.verdict),
             "why": flags.get(m.name) or ("within the marginal band" if m.verdict is Verdict.REVIEW else ""),
             "detail": m.note or ""}
            for m in measured if m.verdict in (Verdict.FAIL, Verdict.REVIEW)]


def technician_details(record: RunRecord) -> str:
    """What a technician needs beside the operator's verdict: a FAIL's cause (the notes of what failed —
    the parameter to set, the orientation found) and every flagged measurement's note; "" when none.
    An ERROR's or an abort's cause stays the operator's line: it says why the station could not judge."""
    parts = [record.cause] if str(record.verdict) == "fail" and record.cause else []
    for m in verdicts(record.measurements):
        if m.note and m.verdict in (Verdict.FAIL, Verdict.REVIEW) and not any(m.note in p for p in parts):
            parts.append(m.note)
    return "; ".join(parts)


def label_of(name: str, owner: bool = True) -> str:
    """A measurement in words (the catalogue's meaning, or the meaning its plugin declared, capitalised), the
    compass or pair it is of in front unless ``owner`` is False: "compass 2: Hard-iron offset, x"."""
    meaning = CATALOGUE.get(base_name(name), ("", ""))[1] or DECLARED_MEANINGS.get(base_name(name), "")
    if not meaning:
        return name
    if not owner:
        return meaning[0].upper() + meaning[1:]
    prefix = name[: len(name) - len(base_name(name))].rstrip(".")
    owner = ("compass " + prefix[3:] + ": ") if prefix.startswith("mag") and "-" not in prefix else (
        f"compasses {prefix.replace('mag', '').replace('-', ' and ')}: " if prefix else "")
    return owner + meaning[0].upper() + meaning[1:]


def sensor_cards(record: RunRecord) -> list[dict[str, Any]]:
    """A unit with several magnetometers: one card per compass, then the pairs' agreement, each with
    its own verdict, its hard iron and what failed in it — so the operator sees *which* compass to look at
    (the GPS mast's, the board's). One magnetometer: no cards (the verdict says it all).  Pairs that
    agree share one card (three compasses make three pairs: six cards ran off a 1366×768 screen); a
    pair that failed or is marginal has its own."""
    titles = record.sensor_titles()
    if len(titles) < 2:
        return []
    hard_iron = {"": (record.calibration or {}).get("hard_iron_ut")}
    for prefix, other in ((record.calibration or {}).get("magnetometers") or {}).items():
        hard_iron[prefix + "."] = other.get("hard_iron_ut")
    cards, agreeing = [], []
    for prefix, measured in by_sensor(verdicts(record.measurements)).items():
        failed = any(m.verdict is Verdict.FAIL for m in measured)
        marginal = any(m.verdict is Verdict.REVIEW for m in measured)
        pair = "-" in prefix  # mag1-mag2.: a pair; "" and mag2.: a compass
        if pair and not failed and not marginal:
            agreeing.append(_pair_words(prefix))
            continue
        h = hard_iron.get(prefix)
        title = f"agreement {_pair_words(prefix)}" if pair else titles.get(prefix, prefix.rstrip("."))
        detail = ("hard iron [" + ", ".join(fmt(v, digits=3) for v in h) + "] µT") if h else ""
        current = interference_words(record, prefix)
        cards.append({"title": title,
                      "verdict": "fail" if failed else "review" if marginal else "pass",
                      "detail": " · ".join(w for w in (detail, current) if w),
                      "items": verdict_items(record, measured, owner=False)})
    if agreeing:
        cards.append({"title": "agreement", "verdict": "pass", "detail": " · ".join(agreeing), "items": []})
    return cards


def interference_words(record: RunRecord, prefix: str) -> str:
    """A compass's current interference as the operator reads it: "38 % of the field at 40 A — grey
    zone" (ArduPilot's bands); empty when it was not measured."""
    pct = next((m.value for m in verdicts(record.measurements) if m.name == prefix + "interference_pct_at_max"),
               None)
    top = ((record.unit_info or {}).get("interference") or {}).get("current_max_a")
    if pct is None or top is None:
        return ""
    return f"{pct:.0f} % of the field at {top:g} A — {zone_words(pct)}"


def _pair_words(prefix: str) -> str:
    """``mag1-mag2.`` → "mag1 and mag2", as the console titles a pair's section."""
    return prefix.rstrip(".").replace("-", " and ")
