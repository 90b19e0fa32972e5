"""Progress of long commands, on a terminal and in a log.

On a terminal, rich's bar redraws one line and vanishes at the end. Elsewhere (CI logs, nohup, a
pipe) rich draws nothing at all, so a run of many minutes would print nothing until it ends;
there :class:`LogProgress` writes a plain line at most every :data:`LOG_INTERVAL_S` seconds and
one when the work ends, each a complete line a log keeps. Both go to stderr, so stdout keeps
only results.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

# a line every 10 s: a 20-minute survey leaves ~120 lines, a 20-second sample one or two
LOG_INTERVAL_S = 10.0


class LogProgress:
    """Progress as complete lines: ``label: 120/870 frames (14 %), 12 s, about 75 s left``."""

    def __init__(self, label: str, total: int | None, unit: str, echo: Callable[[str], None], clock: Callable[[], float], interval_s: float = LOG_INTERVAL_S):
        self.label, self.total, self.unit = label, total, unit
        self.done = 0
        self._echo, self._clock, self._interval = echo, clock, interval_s
        self._start = self._last = clock()

    def advance(self, count: int = 1) -> None:
        self.done += count
        now = self._clock()
        if now - self._last >= self._interval:
            self._last = now
            self._echo(self._line(now))

    def finish(self) -> None:
        self._echo(f"{self.label}: {self.done} {self.unit} in {self._clock() - self._start:.0f} s")

    def _line(self, now: float) -> str:
        elapsed = now - self._start
        if not self.total:
            return f"{self.label}: {self.done} {self.unit}, {elapsed:.0f} s"
        line = f"{self.label}: {self.done}/{self.total} {self.unit} ({100 * self.done / self.total:.0f} %), {elapsed:.0f} s"
        if 0 < self.done < self.total:
            line += f", about {elapsed * (self.total - self.done) / self.done:.0f} s left"
        return line


class _RichProgress:
    def __init__(self, progress, task) -> None:
        self._progress, self._task = progress, task

    @property
    def total(self) -> int | None:
        return self._progress.tasks[0].total

    @total.setter
    def total(self, value: int | None) -> None:
        self._progress.update(self._task, total=value)

    def advance(self, count: int = 1) -> None:
        self._progress.advance(self._task, count)


@contextmanager
def progress_of(label: str, total: int | None, unit: str = "frames", terminal: bool | None = None) -> Iterator[LogProgress | _RichProgress]:
    """A progress reporter (``advance(n)``, settable ``total``): rich's bar on a terminal, else
    :class:`LogProgress` lines on stderr."""
    if terminal if terminal is not None else sys.stderr.isatty():
        from rich.progress import Progress

        with Progress(transient=True) as progress:
            yield _RichProgress(progress, progress.add_task(label, total=total))
        return
    reporter = LogProgress(label, total, unit, lambda text: print(text, file=sys.stderr, flush=True), time.monotonic)
    yield reporter
    reporter.finish()


@contextmanager
def status_of(text: str, terminal: bool | None = None) -> Iterator[None]:
    """A step without a count (an end-of-run adjustment): rich's spinner on a terminal, else one
    line when it starts."""
    if terminal if terminal is not None else sys.stderr.isatty():
        from rich.console import Console

        with Console(stderr=True).status(text):
            yield
        return
    print(f"{text} ...", file=sys.stderr, flush=True)
    yield


def progress_line(text: str) -> None:
    """A batch's events (jobs done, running, failed, time left): whole lines with the time, on
    stderr, the same on a terminal and in a log."""
    print(f"[{time.strftime('%H:%M:%S')}] {text}", file=sys.stderr, flush=True)
