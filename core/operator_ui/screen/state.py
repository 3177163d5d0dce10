"""What the station screen shows, built only from the listener hooks the console also implements
(one source of truth: the page and the console cannot disagree), plus the station's standing
state (field reference, results store) read after each unit.

The bins' centres are not part of the state (the page fetches them once per bin count, see
``bin_centres``): every update stays a few hundred bytes at 200 samples/s.

The state is one JSON-able dictionary with a version number; every change bumps the version and
wakes the event streams, which send the whole state (a reload or a reconnect sees the run in
progress, never a partial picture).
"""

from __future__ import annotations

import threading
import time
from typing import TYPE_CHECKING, Any

from magline.core.measurements import verdicts
from magline.core.operator_ui.cradle import cradle_svg
from magline.core.operator_ui.screen.sides import MISSING_WORDS, SIDES, missing_sides
from magline.core.operator_ui.verdict_words import sensor_cards, shown_verdict, technician_details, verdict_items
from magline.core.plugins import hookimpl
from magline.core.sequencer.batch import Batch
from magline.core.sequencer.sequencer import OPTIONAL_PHASES, PHASES
from magline.core.text import stop_line

if TYPE_CHECKING:
    from magline.core.record import PhaseResult, RunRecord

RECENT = 12  # units listed on the screen


class ScreenState:
    def __init__(self, station: Any) -> None:
        self.prompts = station.prompts
        self._lock = threading.Condition()
        self.version = 0
        self.batch = Batch()
        self.state: dict[str, Any] = {
            "station": {"id": station.station.id, "line": station.station.line, "parts": list(station.products),
                        "serial_prompt": station.prompts.serial,
                        "default_part": station.default_part or next(iter(station.products)),
                        "slots": [{"id": s.id, "part": s.part} for s in station.slots]},
            "sides": side_labels(),  # the sphere's six words (core/operator_ui/screen/sides.py)
            "missing_words": MISSING_WORDS,
            # refusal: why the station did not start what was asked (not a unit's verdict: nothing recorded)
            "busy": False, "run": None, "result": None, "refusal": None,
            "recent": [],
            "shift": {"units": 0, "fpy": None, "word": "this shift" if station.station.shifts else "today"},
            # a station with slots: one run and one result per slot (the page draws one panel each)
            "slots": {}, "round": None,
            "field": {}, "store": {}, "sent_at_ms": 0.0,
            # the operator's yes asked for (the propellers off before a motor test): {"id", "text"} or None
            "question": None,
        }
        self._from_store = False  # the shift's figures come from the results store (else: counted here)
        self._answers: dict[int, bool] = {}
        self._questions = 0

    # ------------------------------------------------------------------ reading
    def snapshot(self) -> tuple[int, dict[str, Any]]:
        with self._lock:
            return self.version, {**self.state, "sent_at_ms": time.time() * 1e3}

    def testing(self) -> bool:
        """Is a unit (or a load) shown as under test? False once its verdict (or a refusal) is shown, while
        its worker may still be winding down."""
        with self._lock:
            return bool(self.state["busy"])

    def wait_newer(self, version: int, timeout: float) -> bool:
        """Block until the state is newer than ``version`` (or ``timeout``): the event stream's pace."""
        with self._lock:
            return self._lock.wait_for(lambda: self.version > version, timeout)

    def _changed(self) -> None:
        self.version += 1
        self._lock.notify_all()

    def update(self, **changes: Any) -> None:
        with self._lock:
            self.state.update(changes)
            self._changed()

    # ------------------------------------------------------------------ a unit starts
    def unit_started(self, serial: str, part: str) -> None:
        with self._lock:
            self.state.update(busy=True, result=None, refusal=None, slots={}, run=_new_run(serial, part))
            self._changed()

    def slots_started(self, serials: dict[str, str], parts: dict[str, str]) -> None:
        """The units of a slot station's load (slots left empty are not shown as running)."""
        with self._lock:
            self.state.update(busy=True, result=None, refusal=None, run=None, round=None, slots={
                slot: {"run": _new_run(serial, parts[slot]), "result": None} for slot, serial in serials.items()})
            self._changed()

    def _run_of(self, run: Any) -> dict[str, Any] | None:
        """The live run dictionary a hook's unit belongs to (its slot's, or the one unit's)."""
        slot = getattr(run, "slot", None)
        if slot is None:
            return self.state["run"]
        entry = self.state["slots"].get(slot)
        return entry["run"] if entry else None

    def unit_refused(self, message: str) -> None:
        """A start the station refused before any record (another run holds the station, the vehicle or
        the serial; a fault before the first phase): a refusal, not a unit's verdict."""
        with self._lock:
            self.state.update(busy=False, run=None, result=None, refusal=message)
            self._changed()

    def _phase(self, run: Any, name: str) -> dict[str, Any] | None:
        """The phase's row; a phase only some products run (the current sweep) gets its row in phase
        order when it starts, so the others never show one pending forever."""
        current = self._run_of(run)
        if not current:
            return None
        found = next((p for p in current["phases"] if p["name"] == name), None)
        if found is None and name in PHASES:
            found = {"name": name, "state": "pending", "duration_s": None}
            after = [p["name"] for p in current["phases"]]
            at = next((i for i, p in enumerate(after) if PHASES.index(p) > PHASES.index(name)), len(after))
            current["phases"].insert(at, found)
        return found

    # ------------------------------------------------------------------ listener hooks
    @hookimpl
    def magline_phase_started(self, run: Any, phase: str) -> None:
        with self._lock:
            entry = self._phase(run, phase)
            if entry is not None:
                entry["state"] = "running"
                self._run_of(run)["waiting"] = None
                self._changed()

    @hookimpl
    def magline_phase_finished(self, run: Any, phase: str, result: PhaseResult) -> None:
        with self._lock:
            entry = self._phase(run, phase)
            if entry is not None:
                entry.update(state=str(result.outcome), duration_s=round(result.duration_s, 2))
                self._run_of(run)["waiting"] = None
                self._changed()

    @hookimpl
    def magline_acquisition_progress(self, run: Any, attempt: int, samples: int, coverage: float, target: float,
                                     bins: Any, n_bins: int | None) -> None:
        with self._lock:
            current = self._run_of(run)
            if current is None:
                return
            bins = list(bins or [])
            # a coil turns the field, not the unit: its directions light the sphere, but there is no side
            # to turn and no count to fill (the schedule ends the acquisition)
            turns_unit = run.unit_moves
            if n_bins and turns_unit and (bins != current["bins"] or not current.get("missing_for")):
                current["missing"] = missing_sides(bins, n_bins)  # in words: what the operator turns next
                current["missing_for"] = n_bins
            current.update(attempt=attempt, samples=samples, coverage=coverage, target=target, n_bins=n_bins,
                           target_samples=run.station.acquisition.samples if turns_unit else None, bins=bins,
                           turns_unit=turns_unit,
                           progress_at_ms=time.time() * 1e3)  # when these samples reached the sequencer
            self._changed()

    @hookimpl
    def magline_acquisition_stopped(self, run: Any, attempt: int, reason: str, after_s: float, readings: int) -> None:
        with self._lock:
            current = self._run_of(run)
            if current is not None:
                line = stop_line(reason, after_s, readings, run.unit_moves)
                current["stopped"] = {"attempt": attempt, "reason": reason, "after_s": round(after_s, 1),
                                      "readings": readings, "line": line}
                self._changed()

    @hookimpl
    def magline_tilt_guidance(self, run: Any, guidance: dict) -> None:
        """A turntable's cradle: the tilt asked for in words and drawn (side and rear views)."""
        with self._lock:
            current = self._run_of(run)
            if current is not None:
                current["tilt"] = {**guidance, "svg": cradle_svg(guidance["pitch_deg"], guidance["roll_deg"],
                                                                 guidance["asked"])}
                self._changed()

    @hookimpl
    def magline_operator_prompt(self, run: Any, message: str) -> None:
        with self._lock:
            current = self._run_of(run)
            if current is not None:
                current["prompt"] = message
                current["prompts"].append(message)
                self._changed()

    @hookimpl
    def magline_operator_confirm(self, run: Any, question: str, timeout_s: float) -> bool | None:
        """The question on the screen with a yes and a no; the unit's thread waits for the answer (no
        answer in time is a no).  Several screens or slots ask one at a time."""
        with self._lock:
            self._questions += 1
            asked = self._questions
            self.state["question"] = {"id": asked, "text": question, "slot": getattr(run, "slot", None)}
            self._changed()
            self._lock.wait_for(lambda: asked in self._answers, timeout_s)
            answer = self._answers.pop(asked, False)
            self.state["question"] = None
            self._changed()
            return answer

    def answer(self, question_id: int, yes: bool) -> bool:
        """The operator's answer from the page; False when that question is no longer asked."""
        with self._lock:
            asked = self.state.get("question")
            if not asked or asked["id"] != question_id:
                return False
            self._answers[question_id] = bool(yes)
            self._changed()
            return True

    @hookimpl
    def magline_waiting(self, run: Any, what: str, elapsed_s: float, limit_s: float | None) -> None:
        with self._lock:
            current = self._run_of(run)
            if current is not None:
                current["waiting"] = {"what": what, "elapsed_s": round(elapsed_s, 1), "limit_s": limit_s}
                self._changed()

    @hookimpl
    def magline_wait_ended(self, run: Any, what: str, waited_s: float) -> None:
        with self._lock:
            current = self._run_of(run)
            if current is not None and (current["waiting"] or {}).get("what") == what:
                current["waiting"] = None
                self._changed()

    @hookimpl
    def magline_motion_started(self, round: int, slots: list[str], motion: str) -> None:
        with self._lock:
            self.state["round"] = {"number": round, "slots": slots, "motion": motion, "moving": True}
            self._changed()

    @hookimpl
    def magline_motion_stopped(self, round: int, slots: list[str], motion: str) -> None:
        with self._lock:
            self.state["round"] = {"number": round, "slots": slots, "motion": motion, "moving": False}
            self._changed()

    @hookimpl
    def magline_unit_finished(self, run: Any, record: RunRecord) -> None:
        with self._lock:
            self.batch.add(record)
            passed, judged = self.batch.first_pass_yield()
            items = verdict_items(record, verdicts(record.measurements))
            shown = shown_verdict(record)
            result = {"verdict": shown, "serial": record.serial, "part": record.part, "slot": record.slot,
                      # a FAIL's cause is the technician's (its rows say in words what failed); an ERROR's
                      # is why the station could not judge the unit: the operator's
                      "cause": "" if str(record.verdict) == "fail" else record.cause,
                      "technician": technician_details(record),
                      "items": items, "sensors": sensor_cards(record),
                      "store": record.store or "NOT stored",
                      "action": self.prompts.action(shown),
                      "report": record.report.rsplit("/", 1)[-1] if record.report else None}
            self.state["recent"] = ([{"serial": record.serial, "part": record.part, "verdict": shown,
                                      "slot": record.slot, "finished": record.finished}]
                                    + self.state["recent"])[:RECENT]
            if self._from_store:  # one more than the store said, until it is read again (right after this)
                self.state["shift"] = {**self.state["shift"], "units": self.state["shift"]["units"] + 1}
            else:
                self.state["shift"] = {**self.state["shift"], "units": self.batch.units, "first_pass": passed,
                                       "judged": judged, "fpy": passed / judged if judged else None}
            if record.slot is not None and record.slot in self.state["slots"]:
                self.state["slots"][record.slot]["result"] = result
            else:
                self.state["result"] = result
                self.state["busy"] = False
            self._changed()

    def forget_result(self) -> None:
        """A scan refused by a label rule: the previous unit's verdict is taken off the screen (it stays in
        the recent units), so the refusal is not read as that unit's."""
        with self._lock:
            if self.state["result"] is not None or self.state["slots"]:
                self.state.update(result=None, slots={})
                self._changed()

    def units_from_store(self, summary: dict[str, Any]) -> None:
        """The shift's count, first-pass yield and recent units as the results store holds them
        (:mod:`magline.core.operator_ui.screen.shift_store`): every screen of the station agrees."""
        with self._lock:
            self._from_store = True
            shift = {**self.state["shift"], **{k: summary[k] for k in ("units", "first_pass", "judged", "fpy")}}
            if shift == self.state["shift"] and summary["recent"] == self.state["recent"]:
                return
            if summary["recent"] != self.state["recent"] and not self.state["busy"]:
                self.state["refusal"] = None  # a unit recorded since: "busy testing …" is old news
            self.state["shift"], self.state["recent"] = shift, summary["recent"]
            self._changed()

    def load_finished(self) -> None:
        """Every slot of the load has its verdict: the station takes the next load."""
        with self._lock:
            self.state["busy"] = False
            self._changed()


def side_labels() -> list[dict[str, object]]:
    """The six words of :mod:`magline.core.operator_ui.screen.sides` where the sphere shows them."""
    return [{"name": name, "at": list(axis)} for name, axis in SIDES]


def bin_centres(n_bins: int) -> list[list[float]]:
    """The centres of the coverage bins, the same ``fibonacci_sphere`` the coverage figure bins on."""
    from magline.core.fit.coverage import fibonacci_sphere

    return [[round(v, 4) for v in c] for c in fibonacci_sphere(n_bins).tolist()]


def _new_run(serial: str, part: str) -> dict[str, Any]:
    return {"serial": serial, "part": part, "attempt": 0, "prompt": "", "prompts": [], "tilt": None, "samples": 0,
            "target_samples": None, "coverage": 0.0, "target": None, "bins": [], "n_bins": None, "missing": [],
            "turns_unit": True,
            "waiting": None, "phases": [{"name": p, "state": "pending", "duration_s": None} for p in PHASES
                                        if p not in OPTIONAL_PHASES]}
