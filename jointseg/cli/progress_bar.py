"""Turn the library's ``progress(stage, fraction)`` calls into a terminal progress bar."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

from rich.console import Console
from rich.progress import (
    BarColumn,
    Progress,
    TaskID,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

from jointseg.progress import ProgressFn

stderr_console = Console(stderr=True)


@contextmanager
def progress_bar(*, enabled: bool = True) -> Iterator[ProgressFn]:
    """Yield a progress callback that draws one bar per stage on stderr.

    The bars are drawn only when stderr is a terminal, so piped output stays clean.
    """
    with Progress(
        TextColumn("[bold]{task.description:<12}"),
        BarColumn(),
        TextColumn("{task.percentage:>5.1f}%"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=stderr_console,
        disable=not enabled or not stderr_console.is_terminal,
        transient=False,
    ) as bar:
        tasks: dict[str, TaskID] = {}

        def update(stage: str, fraction: float) -> None:
            if stage not in tasks:
                tasks[stage] = bar.add_task(stage, total=1.0)
            bar.update(tasks[stage], completed=fraction)

        yield update
