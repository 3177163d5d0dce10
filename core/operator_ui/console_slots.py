"""The operator console on a station with slots: one panel per slot.

Why apart from the one-unit console: several units run at once, so a single progress bar and a
running log would interleave.  On a terminal a live board shows one panel per slot (unit, phase,
attempt, coverage, last message) above which each unit's verdict panel is printed as it ends; on
a pipe or a log file every line carries its slot (``[B] acquire …``) and coverage is printed in
steps.  The shared motion's rounds are said once, for all slots.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import TYPE_CHECKING

from rich.columns import Columns
from rich.console import Console
from rich.live import Live
from rich.panel import Panel

from magline.core.record import Outcome
from magline.core.text import percent, seconds

if TYPE_CHECKING:
    from magline.core.record import PhaseResult, RunRecord
    from magline.core.sequencer.context import RunContext

STYLE = {Outcome.PASS: "green", Outcome.FAIL: "red", Outcome.ERROR: "magenta", Outcome.ABORTED: "yellow",
         Outcome.SKIPPED: "dim", Outcome.INCOMPLETE: "magenta"}
STEP_PCT = 25  # plain consoles print a slot's coverage in steps this wide


@dataclass
class SlotView:
    serial: str
    part: str
    phase: str = ""
    attempt: int = 0
    samples: int = 0
    coverage: float = 0.0
    target: float = 0.0
    message: str = ""
    message_is_wait: bool = False  # the message counts a wait: its end takes it down
    verdict: str = ""
    printed_pct: int = -STEP_PCT


class SlotBoard:
    def __init__(self, console: Console, live: bool) -> None:
        self.console = console
        self.live = live
        self.views: dict[str, SlotView] = {}
        self._lock = threading.RLock()
        self._board: Live | None = None

    # ------------------------------------------------------------------ drawing
    def _panel(self, slot: str, view: SlotView) -> Panel:
        lines = [f"{view.serial}  {view.part}", f"phase: {view.phase or '—'}"]
        if view.attempt:
            lines.append(f"attempt {view.attempt}: {view.samples} readings, coverage {percent(view.coverage)} "
                         f"(target {percent(view.target)})")
        if view.message:
            lines.append(view.message)
        style = STYLE.get(Outcome(view.verdict), "white") if view.verdict else "blue"
        title = f"slot {slot}" + (f" · {view.verdict.upper()}" if view.verdict else "")
        return Panel("\n".join(lines), title=title, border_style=style, width=44)

    def _render(self) -> Columns:
        return Columns([self._panel(slot, view) for slot, view in self.views.items()])

    def _refresh(self) -> None:
        if self._board is not None:
            self._board.update(self._render())

    def _say(self, slot: str, text: str) -> None:
        if not self.live:
            self.console.print(f"[bold][{slot}][/bold] {text}")

    # ------------------------------------------------------------------ listener calls (from slot threads)
    def phase_started(self, run: RunContext, phase: str) -> None:
        with self._lock:
            view = self.views.get(run.slot)
            if view is None or view.verdict:
                view = self.views[run.slot] = SlotView(run.serial, run.part)
                if self.live and self._board is None:
                    self._board = Live(self._render(), console=self.console, refresh_per_second=4)
                    self._board.start()
            view.phase = phase
            self._refresh()
            if phase != "record":
                self._say(run.slot, f"{phase} …")

    def phase_finished(self, run: RunContext, phase: str, result: PhaseResult) -> None:
        with self._lock:
            view = self.views[run.slot]
            if result.message:
                view.message, view.message_is_wait = result.message, False
            self._refresh()
            if phase != "record" or result.outcome is not Outcome.PASS:
                text = f"[{STYLE[result.outcome]}]{phase} {result.outcome.upper()}[/] ({seconds(result.duration_s)})"
                self._say(run.slot, text + (f": {result.message}" if result.message else ""))

    def prompt(self, run: RunContext, message: str) -> None:
        with self._lock:
            view = self.views[run.slot]
            view.message, view.message_is_wait = message, False
            self._refresh()
            self._say(run.slot, f"[bold yellow]>>> {message}[/]")

    def progress(self, run: RunContext, attempt: int, samples: int, coverage: float, target: float) -> None:
        with self._lock:
            view = self.views[run.slot]
            if attempt != view.attempt:
                view.printed_pct = -STEP_PCT
            view.attempt, view.samples, view.coverage, view.target = attempt, samples, coverage, target
            self._refresh()
            pct = int(coverage * 100)
            if pct - view.printed_pct >= STEP_PCT:
                view.printed_pct = pct
                self._say(run.slot, f"attempt {attempt}: {samples} readings, coverage {pct}% "
                                    f"(target {percent(target)})")

    def note(self, run: RunContext, line: str) -> None:
        """A one-off line for a slot (its tumble ended), also shown as the slot's message."""
        with self._lock:
            self.views[run.slot].message = line
            self._refresh()
            self._say(run.slot, line)

    def waiting(self, run: RunContext, what: str, elapsed_s: float, limit_s: float | None) -> None:
        with self._lock:
            left = f", {max(limit_s - elapsed_s, 0):.0f} s left" if limit_s else ""
            view = self.views[run.slot]
            view.message, view.message_is_wait = f"{what} ({elapsed_s:.0f} s{left})", True
            self._refresh()

    def wait_ended(self, run: RunContext) -> None:
        with self._lock:
            view = self.views[run.slot]
            if view.message_is_wait:
                view.message, view.message_is_wait = "", False
                self._refresh()

    def round(self, text: str) -> None:
        with self._lock:
            self.console.print(f"[bold]{text}[/bold]")

    def finished(self, run: RunContext, record: RunRecord, panel: Panel, last: str) -> None:
        """The unit's verdict panel and its closing line (verdict, serial, what to do), printed above the
        live board; the board ends with the last slot."""
        with self._lock:
            self.views[run.slot].verdict = str(record.verdict)
            self.console.print(panel, soft_wrap=False)  # wrapped inside the panel, never cropped
            self.console.print(last)
            self._refresh()
            if all(v.verdict for v in self.views.values()) and self._board is not None:
                self._board.stop()
                self._board = None
