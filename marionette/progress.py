"""Progress reporting: rich bars on stderr, or silence."""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Callable, Iterator

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

__all__ = ["Reporter", "ProgressCallback"]

#: ``callback(done, total)``, called as work advances.
ProgressCallback = Callable[[int, int], None]


class Reporter:
    """Shows one progress bar per stage and short messages, unless quiet."""

    def __init__(self, quiet: bool = False) -> None:
        self.quiet = quiet
        self.console = Console(stderr=True, quiet=quiet)

    def message(self, text: str) -> None:
        self.console.print(text, highlight=False)

    @contextlib.contextmanager
    def stage(self, description: str, total: int | None = None) -> Iterator[ProgressCallback]:
        """A progress bar for one stage; yields a ``(done, total)`` callback."""
        if self.quiet or not sys.stderr:
            yield lambda done, total: None
            return
        columns = [TextColumn("{task.description:<22}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn()]
        with Progress(*columns, console=self.console, transient=False) as bar:
            task = bar.add_task(description, total=total)

            def update(done: int, total_: int) -> None:
                bar.update(task, completed=done, total=total_)

            yield update
            bar.update(task, completed=bar.tasks[0].total or 1, total=bar.tasks[0].total or 1)
