"""Operator console: a listener plugin that shows phases, coverage and the verdict.

Why rich: it gives a live coverage bar and coloured panels on a terminal and degrades to plain
lines when stdout is a pipe or a log file (no escape codes in CI logs or line-PC transcripts).
"""

from __future__ import annotations

from rich.console import Console
from rich.panel import Panel
from rich.progress import BarColumn, Progress, TaskID, TextColumn

from magline.core.measurements import Verdict, verdicts
from magline.core.plugins import hookimpl
from magline.core.record import Outcome, PhaseResult, RunRecord
from magline.core.sequencer.context import RunContext

STYLE = {Outcome.PASS: "green", Outcome.FAIL: "red", Outcome.ERROR: "magenta", Outcome.SKIPPED: "dim"}


class OperatorConsole:
    """Register an instance with the plugin manager (``load_plugins(extra=[console])``)."""

    def __init__(self, console: Console | None = None) -> None:
        self.console = console or Console(highlight=False)
        self.live = self.console.is_terminal
        self._progress: Progress | None = None
        self._task: TaskID | None = None
        self._attempt = 0
        self._last_pct = -1

    @hookimpl
    def magline_phase_started(self, run: RunContext, phase: str) -> None:
        if phase != "record":
            self.console.print(f"[bold]{phase:>9}[/bold] …")

    @hookimpl
    def magline_phase_finished(self, run: RunContext, phase: str, result: PhaseResult) -> None:
        self._stop_progress()
        if phase == "record":
            return
        text = f"[{STYLE[result.outcome]}]{phase:>9} {result.outcome.upper()}[/] ({result.duration_s:.2f} s)"
        if result.message:
            text += f": {result.message}"
        self.console.print(text)

    @hookimpl
    def magline_operator_prompt(self, run: RunContext, message: str) -> None:
        self.console.print(f"[bold yellow]>>> {message}[/]")

    @hookimpl
    def magline_acquisition_progress(self, run: RunContext, attempt: int, samples: int, coverage: float,
                                     target: float) -> None:
        pct = int(coverage * 100)
        if not self.live:
            if attempt != self._attempt or pct // 10 != self._last_pct // 10:
                self.console.print(f"    attempt {attempt}: {samples} samples, coverage {pct}% "
                                   f"(target {target:.0%})")
            self._attempt, self._last_pct = attempt, pct
            return
        if self._progress is None or attempt != self._attempt:
            self._stop_progress()
            self._progress = Progress(TextColumn("    coverage"), BarColumn(),
                                      TextColumn("{task.percentage:>3.0f}% (target {task.fields[target]:.0%})"
                                                 " {task.fields[samples]} samples"),
                                      console=self.console, transient=False)
            self._task = self._progress.add_task("coverage", total=100, target=target, samples=0)
            self._progress.start()
            self._attempt = attempt
        self._progress.update(self._task, completed=pct, samples=samples)

    def _stop_progress(self) -> None:
        if self._progress is not None:
            self._progress.stop()
            self._progress = None

    @hookimpl
    def magline_unit_finished(self, run: RunContext, record: RunRecord) -> None:
        lines = [f"unit {record.serial}  part {record.part}  station {record.station_id}"]
        failed = [m for m in verdicts(record.measurements) if m.verdict is Verdict.FAIL]
        for m in failed:
            lines.append(f"  ✗ {m.name} = {m.value:.4g} {m.unit}  limits [{m.low}, {m.high}]")
        review = [m for m in verdicts(record.measurements) if m.verdict is Verdict.REVIEW]
        for m in review:
            lines.append(f"  ! {m.name} = {m.value:.4g} {m.unit}  (marginal, for review)")
        if record.cause:
            lines.append(f"  cause: {record.cause}")
        if record.calibration:
            h = record.calibration["hard_iron_ut"]
            lines.append(f"  offset [{h[0]:.2f}, {h[1]:.2f}, {h[2]:.2f}] µT, field "
                         f"{record.calibration['field_ut']:.2f} µT, attempts {len(record.attempts)}")
        style = STYLE.get(record.verdict, "red")
        self.console.print(Panel("\n".join(lines), title=f"[bold {style}]{record.verdict.upper()}[/]",
                                 border_style=style, expand=False))
