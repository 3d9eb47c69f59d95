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
