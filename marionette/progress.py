"""Progress reporting: rich bars and messages on stderr, stage timings, or silence."""

from __future__ import annotations

import contextlib
import sys
import time
from collections.abc import Callable, Iterator

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

__all__ = ["Reporter", "ProgressCallback"]

#: ``callback(done, total)``, called as work advances.
ProgressCallback = Callable[[int, int], None]


class Reporter:
    """One progress bar per stage and short messages on stderr, unless quiet.

    Every stage's wall-clock time is added to :attr:`timings` (seconds, by
    stage description), quiet or not; ``verbose`` also prints each stage's
    time and the :meth:`detail` lines.
    """

    def __init__(self, quiet: bool = False, verbose: bool = False) -> None:
        self.quiet = quiet
        self.verbose = verbose and not quiet
        self.console = Console(stderr=True, quiet=quiet)
        self.timings: dict[str, float] = {}

    def message(self, text: str) -> None:
        """A line on stderr (never wrapped: one message, one line, in a log too)."""
        self.console.print(text, highlight=False, soft_wrap=True)

    def detail(self, text: str) -> None:
        """A line shown only with ``verbose``."""
        if self.verbose:
            self.console.print(text, highlight=False, style="dim", soft_wrap=True)

    @contextlib.contextmanager
    def stage(self, description: str, total: int | None = None) -> Iterator[ProgressCallback]:
        """A progress bar for one stage; yields a ``(done, total)`` callback.

        On a terminal the bar is live (and erased if the stage fails); in a
        log (stderr redirected) each finished stage is one line.
        """
        start = time.perf_counter()
        try:
            if self.quiet or not sys.stderr:
                yield lambda done, total: None
            elif self.console.is_terminal:
                yield from self._bar(description, total)
            else:
                yield lambda done, total: None
                self.message(f"{description:<22} done in {time.perf_counter() - start:.1f} s")
        finally:
            elapsed = time.perf_counter() - start
            self.timings[description] = self.timings.get(description, 0.0) + elapsed
        if self.console.is_terminal:  # a log already has the stage's line with its time
            self.detail(f"  {description}: {elapsed:.2f} s")

    def _bar(self, description: str, total: int | None) -> Iterator[ProgressCallback]:
        columns = [TextColumn("{task.description:<22}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn()]
        with Progress(*columns, console=self.console, transient=False) as bar:
            task = bar.add_task(description, total=total)

            def update(done: int, total_: int) -> None:
                bar.update(task, completed=done, total=total_)

            try:
                yield update
            except BaseException:
                bar.live.transient = True  # a failed stage leaves no half-full bar above the error line
                raise
            bar.update(task, completed=bar.tasks[0].total or 1, total=bar.tasks[0].total or 1)
