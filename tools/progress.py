"""The CLI's progress bar for work measured in seconds (of log read, of log simulated)."""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager


@contextmanager
def seconds_bar(label: str, text: str, quiet: bool = False) -> Iterator[Callable[[float, float], None] | None]:
    """A transient bar on stderr (on a terminal, unless `quiet`) that yields tick(done, total) in seconds, or None
    when no bar is shown; `text` formats the count from {task.fields[t]} (done) and {task.total}."""
    if quiet or not sys.stderr.isatty():
        yield None
        return
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    with Progress(TextColumn(label), BarColumn(), TextColumn(text), TimeRemainingColumn(), transient=True) as prog:
        task = prog.add_task(label, total=1.0, t=0.0)
        yield lambda done, total: prog.update(task, total=max(total, 1e-9), completed=done, t=done)


class CountBar:
    """A bar over a count of items (logs of a batch) with a status line printed above it per item; without a
    terminal the lines alone, and with `quiet` nothing."""

    def __init__(self, label: str, unit: str, quiet: bool) -> None:
        self.label, self.unit, self.quiet = label, unit, quiet
        self.prog = self.task = None

    def start(self, total: int) -> None:
        if self.quiet or not sys.stderr.isatty():
            return
        from rich.console import Console
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        self.prog = Progress(TextColumn(f"[bold]{self.label}[/]"), BarColumn(), MofNCompleteColumn(),
                             TextColumn(self.unit), TimeElapsedColumn(), console=Console(stderr=True), transient=True)
        self.prog.start()
        self.task = self.prog.add_task(self.label, total=total)

    def say(self, line: str) -> None:
        if self.quiet:
            return
        if self.prog is not None:
            self.prog.console.print(line, markup=False, highlight=False)
        else:
            print(line, file=sys.stderr, flush=True)

    def advance(self, line: str) -> None:
        self.say(line)
        if self.prog is not None:
            self.prog.advance(self.task)

    def stop(self) -> None:
        if self.prog is not None:
            self.prog.stop()
            self.prog = None


@contextmanager
def count_bar(label: str, unit: str, quiet: bool = False) -> Iterator[CountBar]:
    """A CountBar, stopped however the work ends."""
    bar = CountBar(label, unit, quiet)
    try:
        yield bar
    finally:
        bar.stop()
