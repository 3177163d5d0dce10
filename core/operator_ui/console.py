"""Operator console: a listener plugin that shows phases, coverage, waits and the verdict.

Why rich: it gives a live coverage bar and coloured panels on a terminal and degrades to plain
lines when stdout is a pipe or a log file (no escape codes in CI logs or line-PC transcripts).
What the operator reads is rounded, carries its unit and names no Python class; library chatter
goes to the record's log (see :mod:`magline.core.sequencer.unit_log`), not here.
"""

from __future__ import annotations

import select
import sys
from typing import TYPE_CHECKING

from rich.console import Console
from rich.live import Live
from rich.panel import Panel
from rich.progress import BarColumn, Progress, TaskID, TextColumn
from rich.text import Text

from magline.core.measurements import Verdict, by_sensor, verdicts
from magline.core.operator_ui.console_slots import STYLE, SlotBoard
from magline.core.operator_ui.cradle import cradle_text
from magline.core.operator_ui.screen.sides import MISSING_WORDS, missing_sides
from magline.core.operator_ui.verdict_words import closing_line, interference_words, sensor_cards, shown_verdict
from magline.core.plugins import hookimpl
from magline.core.record import Outcome
from magline.core.text import fmt, percent, seconds, stop_line

if TYPE_CHECKING:
    from magline.core.record import PhaseResult, RunRecord
    from magline.core.sequencer.batch import Batch
    from magline.core.sequencer.context import RunContext

PHASE_WIDTH = 12  # "interference", the longest phase name: the names right-aligned in one column
MARK = {Verdict.PASS: "✓", Verdict.FAIL: "✗", Verdict.REVIEW: "!", Verdict.INFO: "·"}
WAIT_EVERY_S = 5  # plain-text consoles print a countdown line this often


class OperatorConsole:
    """Register an instance with the plugin manager (``load_plugins(extra=[console])``)."""

    def __init__(self, console: Console | None = None) -> None:
        # a terminal's lines wrap at words at its width (the terminal itself wraps mid-word); piped or written
        # to a file, a log line is never cut
        self.console = console or Console(highlight=False)
        if console is None:
            self.console.soft_wrap = not self.console.is_terminal
        self.live = self.console.is_terminal
        self._progress: Progress | None = None
        self._task: TaskID | None = None
        self._attempt = 0
        self._last_pct = -1
        self._last_wait = -1
        self._wait_line: Live | None = None  # a terminal's countdown: one line rewritten in place
        self.slots = SlotBoard(self.console, self.live)  # units of a station with slots, one panel each
        self._bins: tuple[list[int], int | None] = ([], None)  # the coverage's bins, for a turntable's tilt line

    def note(self, text: str) -> None:
        self.console.print(text)

    @hookimpl
    def magline_phase_started(self, run: RunContext, phase: str) -> None:
        if run.slot is not None:
            return self.slots.phase_started(run, phase)
        if phase != "record":
            self.console.print(f"[bold]{phase:>{PHASE_WIDTH}}[/bold] …")

    @hookimpl
    def magline_phase_finished(self, run: RunContext, phase: str, result: PhaseResult) -> None:
        if run.slot is not None:
            return self.slots.phase_finished(run, phase, result)
        self._stop_live()
        self._last_wait = -1
        if phase == "record" and result.outcome is Outcome.PASS:
            return
        text = (f"[{STYLE[result.outcome]}]{phase:>{PHASE_WIDTH}} {result.outcome.upper()}[/] "
                f"({seconds(result.duration_s)})")
        if result.message:
            text += f": {result.message}"
        self.console.print(text)

    @hookimpl
    def magline_operator_prompt(self, run: RunContext, message: str) -> None:
        if run.slot is not None:
            return self.slots.prompt(run, message)
        self.console.print(f"[bold yellow]>>> {message}[/]")

    @hookimpl
    def magline_tilt_guidance(self, run: RunContext, guidance: dict) -> None:
        """The cradle asked for, drawn after the prompt that asks for it (the leader's words name the tilt;
        a slot's board shows the prompt only)."""
        if run.slot is not None or guidance["state"] != "tilt":
            return
        self._stop_progress()
        bins, n_bins = self._bins
        missing = missing_sides(bins, n_bins) if n_bins else []
        still = f" ({MISSING_WORDS}: {', '.join(missing)})" if missing else ""
        self.console.print(f"    cradle {guidance['step']}: {guidance['asked']} — "
                           f"{cradle_text(guidance['pitch_deg'], guidance['roll_deg'])}{still}")

    @hookimpl
    def magline_operator_confirm(self, run: RunContext, question: str, timeout_s: float) -> bool | None:
        """At a terminal: the question, then a line read from it (yes / y; anything else is a no).
        Without a terminal (a pipe, a service) there is nobody to ask here: None."""
        if not self.asks_operator():
            return None
        self._stop_live()
        self.console.print(f"[bold yellow]??? {question} — type yes and Enter[/]")
        answer = self.read_answer(timeout_s)
        return answer is not None and answer.strip().lower() in ("y", "yes")

    def asks_operator(self) -> bool:
        return sys.stdin is not None and sys.stdin.isatty()

    def read_answer(self, timeout_s: float) -> str | None:
        """A line from the terminal, or None when none came within ``timeout_s``."""
        ready, _, _ = select.select([sys.stdin], [], [], timeout_s)
        return sys.stdin.readline() if ready else None

    @hookimpl
    def magline_waiting(self, run: RunContext, what: str, elapsed_s: float, limit_s: float | None) -> None:
        if run.slot is not None:
            return self.slots.waiting(run, what, elapsed_s, limit_s)
        whole = int(elapsed_s)
        left = f"{max(limit_s - elapsed_s, 0):.0f} s left of {limit_s:.0f} s" if limit_s else f"{whole} s"
        line = f"    {what} … {left}"
        if self.live:  # a terminal: the countdown rewrites its one line
            self._stop_progress()
            if self._wait_line is None:
                self._wait_line = Live(Text(line), console=self.console, auto_refresh=False, transient=False)
                self._wait_line.start()
            self._wait_line.update(Text(line), refresh=True)
            return
        if whole // WAIT_EVERY_S == self._last_wait // WAIT_EVERY_S:
            return  # a pipe or a log: a line every few seconds
        self._last_wait = whole
        self.console.print(line)

    @hookimpl
    def magline_wait_ended(self, run: RunContext, what: str, waited_s: float) -> None:
        if run.slot is not None:
            return self.slots.wait_ended(run)
        self._stop_wait_line()
        self._last_wait = -1  # the next wait's countdown starts with its first line

    def _stop_wait_line(self) -> None:
        if self._wait_line is not None:
            self._wait_line.stop()
            self._wait_line = None

    @hookimpl
    def magline_acquisition_progress(self, run: RunContext, attempt: int, samples: int, coverage: float,
                                     target: float, bins: list[int] | None = None, n_bins: int | None = None) -> None:
        self._bins = (bins or [], n_bins)  # what a turntable's next tilt line names as still to cover
        if run.slot is not None:
            return self.slots.progress(run, attempt, samples, coverage, target)
        pct = int(coverage * 100)
        if not self.live:
            if attempt != self._attempt or pct // 10 != self._last_pct // 10:
                self.console.print(f"    attempt {attempt}: {samples} readings, coverage {pct}% "
                                   f"(target {percent(target)})")
            self._attempt, self._last_pct = attempt, pct
            return
        if self._progress is None or attempt != self._attempt:
            self._stop_progress()
            self._stop_wait_line()
            self._progress = Progress(TextColumn("    coverage"), BarColumn(),
                                      TextColumn("{task.percentage:>3.0f}% (target {task.fields[target]:.0%})"
                                                 " {task.fields[samples]} readings"),
                                      console=self.console, transient=False)
            self._task = self._progress.add_task("coverage", total=100, target=target, samples=0)
            self._progress.start()
            self._attempt = attempt
        self._progress.update(self._task, completed=pct, samples=samples)

    @hookimpl
    def magline_acquisition_stopped(self, run: RunContext, attempt: int, reason: str, after_s: float,
                                    readings: int) -> None:
        line = stop_line(reason, after_s, readings, run.unit_moves)
        if run.slot is not None:
            return self.slots.note(run, line)
        self._stop_live()
        self.console.print(f"    [bold green]{line}[/]" if reason == "determined" else f"    {line}")

    def _stop_live(self) -> None:
        """Both live lines (a countdown, a coverage bar) end where they are: plain lines follow."""
        self._stop_wait_line()
        self._stop_progress()

    def _stop_progress(self) -> None:
        if self._progress is not None:
            self._progress.stop()
            self._progress = None

    @hookimpl
    def magline_unit_finished(self, run: RunContext, record: RunRecord) -> None:
        style = STYLE.get(record.verdict, "red")
        title = record.verdict.upper() + (" · REVIEW" if record.review else "")
        if record.slot is not None:
            title = f"slot {record.slot} · {title}"
        panel = verdict_panel(record, title, style)
        # the last line of every unit: what the operator reads to know what to do with it, as the screen says it
        last = f"[bold {style}]{closing_line(record, run.station.prompts.action(shown_verdict(record)))}[/]"
        if run.slot is not None:
            return self.slots.finished(run, record, panel, last)
        self._stop_live()
        self.console.print(panel, soft_wrap=False)  # wrapped inside the panel: no sentence cut at the edge
        self.console.print(last)

    @hookimpl
    def magline_motion_started(self, round: int, slots: list[str], motion: str) -> None:
        if slots != [""]:
            self.slots.round(f"{motion} round {round}: slot{'s' if len(slots) > 1 else ''} {', '.join(slots)} "
                             "sampling")

    @hookimpl
    def magline_motion_stopped(self, round: int, slots: list[str], motion: str) -> None:
        if slots != [""]:
            self.slots.round(f"{motion} round {round} done")

    def batch_summary(self, batch: Batch) -> None:
        self.console.print(f"[bold]{batch.summary()}[/]")


def compass_cards(record: RunRecord) -> list[str]:
    """A unit with several compasses, compact: a line per compass (its verdict and hard iron), under it
    what failed or is flagged in it, then the pairs that agree on one line — so that on an 80×40
    terminal the verdict and what to do stay in view; every measurement is in ``magline show``."""
    lines = []
    for card in sensor_cards(record):
        mark = {"pass": "✓", "fail": "✗", "review": "!"}[card["verdict"]]
        lines.append(f"  {mark} {card['title']}  {card['verdict'].upper()}  {card['detail']}".rstrip())
        lines += [f"      {item['label']} {item['value']} {item['limit']} {item['verdict'].upper()}"
                  + (f" — {item['why']}" if item["why"] else "") for item in card["items"]]
    lines.append(f"  every measurement: magline show {record.run_id}" if record.run_id else
                 "  every measurement: in the record")
    return lines


def verdict_panel(record: RunRecord, title: str, style: str) -> Panel:
    """The panel as printed: its lines wrap at the terminal's width (the console itself never wraps log
    lines, which would crop a panel's long sentences — a safety note, a refusal's advice — at the edge)."""
    return Panel(Text("\n".join(verdict_lines(record)), overflow="fold"), title=f"[bold {style}]{title}[/]",
                 border_style=style, expand=False)


def verdict_lines(record: RunRecord) -> list[str]:
    """The verdict panel: identity, every measurement against its limit, the calibration, where
    the record is kept, and anything the operator must act on (re-test, left changed)."""
    lines = [f"unit {record.serial}  part {record.part}  station {record.station_id}"]
    if record.earlier_passes:
        lines.append(f"  re-test: this unit passed {record.earlier_passes} time(s) before "
                     f"(test {record.earlier_runs + 1} of this serial)")
    if record.cause:
        lines.append(f"  cause: {record.cause}")
    process = {f["name"]: f for f in record.review}
    sensors = record.sensor_titles()
    if len(sensors) > 1:  # several compasses: a card each, as the screen shows them; every row in ``show``
        lines += compass_cards(record)
    for measured in ([] if len(sensors) > 1 else by_sensor(verdicts(record.measurements)).values()):
        for m in measured:
            limit = f"[{fmt(m.low)}, {fmt(m.high)}]" if m.low is not None or m.high is not None else "no limit"
            flag = "  FAIL" if m.verdict is Verdict.FAIL else ""
            if m.verdict is Verdict.REVIEW:
                flag = (f"  REVIEW ({abs(process[m.name]['z']):.1f}σ from the process)" if m.name in process
                        else "  REVIEW (marginal)")
            lines.append(f"  {MARK[m.verdict]} {m.name:<24} {fmt(m.value, m.unit):>14}  {limit}{flag}")
    if record.review:
        lines.append("  FLAGGED FOR ENGINEERING REVIEW (the unit passes):")
        lines += [f"    {f['reason']}" for f in record.review]
    elif record.review_note.startswith("no process review"):
        lines.append(f"  {record.review_note}")
    if record.calibration and len(sensors) < 2:
        cal = record.calibration
        h = ", ".join(fmt(v, digits=4) for v in cal["hard_iron_ut"])
        lines.append(f"  hard iron [{h}] µT, field {fmt(cal['field_ut'], 'µT')}, attempts {len(record.attempts)}")
        if interference_words(record, ""):
            lines.append(f"  current interference: {interference_words(record, '')}")
        for i, row in enumerate(cal["soft_iron"]):
            lines.append(f"  {'soft iron' if i == 0 else '':<9} [" + ", ".join(f"{v:8.4f}" for v in row) + "]")
        for name, other in (cal.get("magnetometers") or {}).items():
            h = ", ".join(fmt(v, digits=4) for v in other["hard_iron_ut"])
            lines.append(f"  {name} ({other['device_id']}): hard iron [{h}] µT")
        affine = cal.get("affine")
        if affine:
            lines.append(f"  coil misalignment {fmt(affine['misalignment_deg'], '°', 3)}")
    if record.unverified_params:
        lines.append(f"  UNVERIFIED: the unit holds a new calibration that was not proven "
                     f"({', '.join(record.unverified_params)}) — re-test it")
    if record.left_changed:
        lines.append("  NOT RESTORED: " + ", ".join(f"{k} left at {v}" for k, v in record.left_changed.items())
                     + " — re-test it")
    lines.append(f"  record: {record.store}" if record.store else "  record: NOT stored")
    if record.report or record.report_error:
        lines.append(f"  report: {record.report}" if record.report else f"  {record.report_error}")
    return lines
