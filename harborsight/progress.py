"""One progress display for every long task (the commands, training): a Rich bar on a
terminal, and on anything else (a CI log, ``| tee``, a file) a plain line every few seconds,
such as

    run: 120/480 frames, 25 %, 0:01:10 elapsed

and a last one when the work ends. A bar on a non-terminal prints nothing until the end
(or nothing at all when it is transient), and its control codes garble a log.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from datetime import timedelta

from rich.console import Console
from rich.markup import escape
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

#: seconds between two plain progress lines
PLAIN_EVERY_S = 5.0


class ProgressReport:
    """What a command tells its progress display: :meth:`advance` per item done,
    :meth:`update` to set the count, the total or a short note (``"3 skipped"``)."""

    def __init__(self, label: str, total: int | None, unit: str, completed: int = 0) -> None:
        self.label, self.total, self.unit = label, total, unit
        self.completed = completed
        self.note = ""
        self._lock = threading.Lock()

    def advance(self, n: int = 1, note: str | None = None) -> None:
        """``n`` more items done; ``note`` replaces the note when given."""
        with self._lock:
            self.completed += n
            if note is not None:
                self.note = note
        self._changed()

    def update(self, *, completed: int | None = None, total: int | None = None,
               note: str | None = None, label: str | None = None) -> None:
        """Set any of the count, the total, the note and the label."""
        with self._lock:
            if completed is not None:
                self.completed = completed
            if total is not None:
                self.total = total
            if note is not None:
                self.note = note
            if label is not None:
                self.label = label
        self._changed()

    def _changed(self) -> None:
        """Hook of the displays."""


def plain_line(label: str, completed: int, total: int | None, unit: str, elapsed_s: float,
               note: str = "", remaining_s: float | None = None) -> str:
    """``run: 120/480 frames, 25 %, 0:01:10 elapsed[, 0:03:30 left][, note]``; without a
    total ``run: 120 frames, 0:01:10 elapsed``."""
    elapsed = str(timedelta(seconds=int(elapsed_s)))
    if total:
        text = f"{label}: {completed}/{total} {unit}, {100 * completed // total} %, {elapsed} elapsed"
    else:
        text = f"{label}: {completed} {unit}, {elapsed} elapsed"
    if remaining_s is not None and math.isfinite(remaining_s):
        text += f", {timedelta(seconds=round(remaining_s))} left"
    return f"{text}, {note}" if note else text


class _PlainReport(ProgressReport):
    """Prints :func:`plain_line` every ``every_s`` seconds from a timer thread (also while
    one item takes long: a log that stays silent for minutes looks hung), and at the end."""

    def __init__(self, label: str, total: int | None, unit: str, completed: int,
                 console: Console, every_s: float, clock: Callable[[], float],
                 remaining: bool) -> None:
        super().__init__(label, total, unit, completed)
        self.console, self.every_s, self.clock, self.remaining = console, every_s, clock, remaining
        self.started = clock()
        self.started_at = completed
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._tick, name="harborsight-progress",
                                        daemon=True)

    def line(self) -> str:
        with self._lock:
            elapsed_s = self.clock() - self.started
            done = self.completed - self.started_at
            remaining_s = None
            if self.remaining and self.total and done > 0 and self.completed < self.total:
                remaining_s = elapsed_s / done * (self.total - self.completed)
            return plain_line(self.label, self.completed, self.total, self.unit, elapsed_s,
                              self.note, remaining_s)

    def print_line(self) -> None:
        self.console.print(self.line(), markup=False, highlight=False, soft_wrap=True)

    def _tick(self) -> None:
        while not self._stop.wait(self.every_s):
            self.print_line()

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()
        self.print_line()


class _BarReport(ProgressReport):
    """Forwards to a Rich progress bar."""

    def __init__(self, label: str, total: int | None, unit: str, completed: int,
                 progress: Progress) -> None:
        super().__init__(label, total, unit, completed)
        self.progress = progress
        self.task = progress.add_task(label, total=total, completed=completed, status="")

    def _changed(self) -> None:
        with self._lock:
            completed, total, note, label = self.completed, self.total, self.note, self.label
        self.progress.update(self.task, completed=completed, total=total,
                             description=label, status=escape(note))


@contextmanager
def progress_report(label: str, total: int | None, console: Console, *, unit: str = "frames",
                    transient: bool = True, enabled: bool = True, completed: int = 0,
                    remaining: bool = False, every_s: float | None = None,
                    clock: Callable[[], float] = time.monotonic) -> Iterator[ProgressReport]:
    """A progress display for ``total`` items (None: unknown) on ``console``: a Rich bar
    when the console is a terminal, else a plain line every ``every_s`` seconds (default
    :data:`PLAIN_EVERY_S`) and one at the end. ``completed``: items already done (a resumed
    run); ``remaining``: also show the time left, from the pace since the start.
    ``enabled=False`` shows nothing (a command's ``--no-progress``). Yields the
    :class:`ProgressReport` to advance."""
    if not enabled:
        yield ProgressReport(label, total, unit, completed)
        return
    if not console.is_terminal:
        report = _PlainReport(label, total, unit, completed, console,
                              PLAIN_EVERY_S if every_s is None else every_s, clock, remaining)
        report.start()
        try:
            yield report
        finally:
            report.stop()
        return
    clock_column = TimeRemainingColumn() if remaining else TimeElapsedColumn()
    with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                  clock_column, TextColumn("{task.fields[status]}"), console=console,
                  transient=transient) as progress:
        yield _BarReport(label, total, unit, completed, progress)
