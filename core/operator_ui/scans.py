"""Serials scanned at a terminal while a unit is under test: queued and said, never echoed into the
progress lines nor started unseen.

Why: a barcode scanner is a keyboard.  An operator scans the next unit's label while the current one
tumbles; the terminal echoed the label into the progress bar, kept it in its line buffer, and the next
``input()`` took it — the next unit started without anyone seeing its serial asked for.  On a terminal
one thread therefore reads every line for the whole batch, the terminal's echo is off while a unit runs
(the label does not land among the progress lines), and a label read then is said at once
("next: LP-002 …") and answers the next prompt, where it is shown after the question.  A pipe (a
scanner script, a test) keeps plain ``input()``: there, serials queued ahead are the input itself.
"""

from __future__ import annotations

import contextlib
import queue
import sys
import termios
import threading
from collections.abc import Callable
from typing import TextIO


class TerminalScans:
    """Lines from a terminal, read by one thread; ``ask`` answers a prompt from them."""

    def __init__(self, say: Callable[[str], None], stdin: TextIO | None = None) -> None:
        self.stdin = stdin or sys.stdin
        self.say = say
        self.fd = self.stdin.fileno()
        self.saved = termios.tcgetattr(self.fd)
        self.lines: queue.Queue[str | None] = queue.Queue()
        self.prompting = threading.Event()
        self.queued = 0  # lines read while no prompt was shown, not yet taken
        self._lock = threading.Lock()
        self._echo(False)  # until the first question: a unit given with --serial may be running
        threading.Thread(target=self._read, name="magline-scans", daemon=True).start()

    def _read(self) -> None:
        while True:
            try:
                line = self.stdin.readline()
            except (OSError, ValueError):  # the terminal went away
                line = ""
            if not line:
                self.lines.put(None)
                return
            with self._lock:
                ahead = not self.prompting.is_set()
                if ahead:
                    self.queued += 1
            if ahead and line.strip():
                self.say(f"next: {line.strip()} — scanned while a unit is under test; it starts when this "
                         "unit ends (an empty line ends the batch instead)")
            self.lines.put(line)

    def ask(self, prompt: str) -> str:
        """The next line (without its newline) as the answer to ``prompt``: one scanned ahead first,
        shown after the question; ``EOFError`` at the end of input."""
        self._echo(True)
        print(prompt, end="", flush=True)
        with self._lock:
            ahead = self.queued > 0
            if ahead:
                self.queued -= 1
            else:
                self.prompting.set()
        try:
            line = self.lines.get()
        finally:
            self.prompting.clear()
            self._echo(False)  # a unit runs from now on until the next question
        if line is None:
            print(flush=True)
            raise EOFError
        if ahead:  # the terminal did not echo it under the question: show what answered
            print(line.strip(), flush=True)
        return line.rstrip("\r\n")

    def _echo(self, on: bool) -> None:
        attrs = termios.tcgetattr(self.fd)
        attrs[3] = attrs[3] | termios.ECHO if on else attrs[3] & ~termios.ECHO
        with contextlib.suppress(termios.error):
            termios.tcsetattr(self.fd, termios.TCSANOW, attrs)

    def close(self) -> None:
        """The terminal as it was (echo on)."""
        with contextlib.suppress(termios.error):
            termios.tcsetattr(self.fd, termios.TCSANOW, self.saved)
