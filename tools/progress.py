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
