"""One progress line for long work (status of a large fleet, a rollout's
waves, enroll's key fetches): done/total, failures, the current wave, time
left, drawn by rich on stderr and erased when the work is done.  Only where
stderr is a terminal (and not TERM=dumb): in a pipe, a file or a CI log there
is none, and the commands print their lines as before."""

from __future__ import annotations

import sys


class Line:
    """``with Line("status", total) as line: line.advance(failed=...)``;
    ``line.enabled`` is False where nothing is drawn (every call is then a
    no-op), ``line.say(text)`` prints a line above it (or on stderr)."""

    def __init__(self, what: str, total: int | None = None, unit: str = "hosts", enabled: bool = True):
        from rich.console import Console

        self.console = Console(stderr=True, highlight=False, soft_wrap=True)
        self.enabled = enabled and self.console.is_terminal and not self.console.is_dumb_terminal
        self.what, self.total, self.unit = what, total, unit
        self.failed = 0
        self._progress = None
        self._wave = ""

    def __enter__(self) -> Line:
        if self.total is not None:
            self.start(self.total)
        return self

    def start(self, total: int) -> None:
        """Draw the line, of ``total`` items (once; where enabled)."""
        self.total = total
        if not self.enabled or self._progress is not None or total <= 0:
            return
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

        self._progress = Progress(
            TextColumn("{task.description}"),
            BarColumn(bar_width=24),
            MofNCompleteColumn(),
            TextColumn(f"{self.unit}, {{task.fields[failed]}} failed{{task.fields[wave]}}, left"),
            TimeRemainingColumn(),
            console=self.console,
            transient=True,  # erased when done: the command's own output follows
        )  # what the command prints meanwhile (sys.stdout, sys.stderr) goes above the line
        self._progress.start()
        self._task = self._progress.add_task(self.what, total=total, failed=self.failed, wave=self._wave)

    def __exit__(self, *exc) -> None:
        if self._progress is not None:
            self._progress.stop()
            self._progress = None

    def advance(self, count: int = 1, failed: int = 0, total: int | None = None) -> None:
        if total is not None and self._progress is None:
            self.start(total)
        self.failed += failed
        if self._progress is not None:
            self._progress.update(self._task, advance=count, failed=self.failed)
            self._progress.refresh()

    def wave(self, text: str) -> None:
        """The current wave (``wave 2/5``), shown in the line."""
        self._wave = f", {text}"
        if self._progress is not None:
            self._progress.update(self._task, wave=self._wave)
            self._progress.refresh()

    def say(self, text: str) -> None:
        """A line of its own on stderr: above the progress line while it is drawn."""
        print(text, file=sys.stderr, flush=True)
