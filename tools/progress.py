"""The CLI's progress bars (the core only calls back): work measured in seconds (of log read, of log simulated),
in items (frames, logs of a batch), and the build's frames."""

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


@contextmanager
def items_bar(label: str, unit: str, quiet: bool = False) -> Iterator[Callable[[int, int], None] | None]:
    """A transient bar on stderr (on a terminal, unless `quiet`) over a count of items: yields tick(done, total),
    or None when no bar is shown."""
    if quiet or not sys.stderr.isatty():
        yield None
        return
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    with Progress(TextColumn(f"[bold]{label}[/]"), BarColumn(), MofNCompleteColumn(), TextColumn(unit),
                  TimeElapsedColumn(), TextColumn("ETA"), TimeRemainingColumn(), transient=True) as prog:
        task = prog.add_task(label, total=None)
        yield lambda done, total: prog.update(task, total=max(total, done), completed=done)


@contextmanager
def build_bar(quiet: bool = False) -> Iterator[Callable | None]:
    """`kosmap build`'s bar: depth frames (or laser scans) done of those expected, their rate and the real-time
    factor; yields the build's `on_progress` (it takes a mapping.build.Progress), or None when no bar is shown."""
    if quiet or not sys.stderr.isatty():
        yield None
        return
    import time

    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    with Progress(TextColumn("[bold]build[/]"), BarColumn(), MofNCompleteColumn(),
                  TextColumn("{task.fields[unit]}, {task.fields[rate]}/s, {task.fields[rt]}× real time"),
                  TimeElapsedColumn(), TextColumn("ETA"), TimeRemainingColumn(), transient=True) as prog:
        task = prog.add_task("build", total=None, rate="–", rt="–", unit="")
        t0 = time.perf_counter()

        def tick(p) -> None:
            el = time.perf_counter() - t0
            prog.update(task, total=p.units, completed=p.done, unit=p.unit,
                        rate=f"{p.done / el:.0f}" if el > 0 else "–", rt=f"{p.log_s / el:.1f}" if el > 0 else "–")

        yield tick
