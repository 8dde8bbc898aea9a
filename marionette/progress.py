"""Progress reporting: rich bars and messages on stderr, stage timings, or silence.

Ctrl-C during a stage is deferred: the signal only sets a flag, and the stage
raises :class:`KeyboardInterrupt` at its next progress call or at its end.
The default handler would raise it wherever Python next runs, which can be
inside a call back from compiled (numba) code or half-way through a pipe
write, and an interrupted parallel kernel has crashed the process (SIGSEGV)
instead of exiting with code 130. Under :func:`sigterm_as_interrupt` (the
command line) SIGTERM is a Ctrl-C too, so ``kill`` cleans up as Ctrl-C does.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

__all__ = ["Reporter", "ProgressCallback", "interrupt_requested", "sigterm_as_interrupt"]

#: ``callback(done, total)``, called as work advances.
ProgressCallback = Callable[[int, int], None]

_interrupt = threading.Event()


def interrupt_requested() -> bool:
    """Whether Ctrl-C arrived during a stage (the error that follows is the interruption)."""
    return _interrupt.is_set()


@contextlib.contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """SIGTERM raises KeyboardInterrupt while this runs, as Ctrl-C does (main thread and SIGTERM at its
    default; else a no-op): outputs staged, temporary folders and cluster workers are then cleaned up."""
    if (threading.current_thread() is not threading.main_thread()
            or signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL):
        yield
        return
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


@contextlib.contextmanager
def _deferred_interrupt() -> Iterator[None]:
    """SIGINT and SIGTERM only set the flag while this runs where they would raise KeyboardInterrupt (main
    thread, Python's own handler in place; else a no-op)."""
    deferred = [s for s in (signal.SIGINT, signal.SIGTERM) if signal.getsignal(s) is signal.default_int_handler]
    if threading.current_thread() is not threading.main_thread() or not deferred:
        yield
        return
    previous = {s: signal.signal(s, lambda signum, frame: _interrupt.set()) for s in deferred}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


def _raise_if_interrupted() -> None:
    """Raise the KeyboardInterrupt of a deferred Ctrl-C (once: the flag is cleared)."""
    if _interrupt.is_set():
        _interrupt.clear()
        raise KeyboardInterrupt


def _checked(callback: ProgressCallback) -> ProgressCallback:
    """``callback`` that first raises KeyboardInterrupt when Ctrl-C has arrived."""
    def progress(done: int, total: int) -> None:
        _raise_if_interrupted()
        callback(done, total)
    return progress


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
    def stage(self, description: str, total: int | None = None, *,
              defer_interrupt: bool = True) -> Iterator[ProgressCallback]:
        """A progress bar for one stage; yields a ``(done, total)`` callback.

        On a terminal the bar is live (and erased if the stage fails); in a
        log (stderr redirected) each finished stage is one line.
        ``defer_interrupt=False`` lets Ctrl-C raise where it lands, for a
        stage that only waits for other processes (which may never call
        back).
        """
        start = time.perf_counter()
        try:
            with _deferred_interrupt() if defer_interrupt else contextlib.nullcontext():
                if self.quiet or not sys.stderr:
                    yield _checked(lambda done, total: None)
                elif self.console.is_terminal:
                    yield from self._bar(description, total)
                else:
                    yield _checked(lambda done, total: None)
                    self.message(f"{description:<22} done in {time.perf_counter() - start:.1f} s")
            _raise_if_interrupted()
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
                yield _checked(update)
            except BaseException:
                bar.live.transient = True  # a failed stage leaves no half-full bar above the error line
                raise
            bar.update(task, completed=bar.tasks[0].total or 1, total=bar.tasks[0].total or 1)
