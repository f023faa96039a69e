"""Progress of a command on stderr: ``rich`` bars on a terminal, plain lines otherwise.

The library reports progress through one callback, ``say(message: str)``; this module turns
those messages into what the user sees, without changing that interface:

- **not a terminal** (a log file, a pipe, CI): each message is one line on stderr, as it comes;
- **a terminal**: a ``rich`` live display, one row per stage of the command (reading, solving,
  chunks, geometry, writing, ...) with its elapsed time; a message that counts (``chunk 3 of 12``,
  ``[4/9]``, ``iteration 3``) advances a bar with its ETA. The messages still scroll above the
  bars, so nothing is hidden.

Verbosity (``-q`` / ``-v``): quiet keeps only the warnings (messages starting ``warning``);
verbose prefixes each line with the time since the command started.
"""

from __future__ import annotations

import re
import sys
import time
from typing import Callable, TextIO

QUIET, NORMAL, VERBOSE = -1, 0, 1

#: stage of a message: the first pattern found in it names the bar it drives
_STAGES = (("reading", re.compile(r"\breading\b")), ("simulating", re.compile(r"\bbuilding track|\bIMU: \d+ samples")),
           ("preintegrating", re.compile(r"\bpreintegrating\b")),
           ("chunks", re.compile(r"^chunk \d+ of \d+")), ("segments", re.compile(r"\bsegments?\b")),
           ("solving", re.compile(r"\bsolving\b|^\s*iteration \d+")),
           ("geometry", re.compile(r"\bgeometry\b")), ("evaluating", re.compile(r"\bevaluating\b")),
           ("writing", re.compile(r"\bwriting\b")), ("batch", re.compile(r"^batch: ")))
_COUNT = re.compile(r"(?:^|\D)(\d+) of (\d+)\b|\[(\d+)/(\d+)\]")
_ITERATION = re.compile(r"^\s*iteration (\d+)")


def stage_of(message: str) -> str | None:
    """The stage a progress message belongs to (None: it only scrolls)."""
    return next((name for name, pattern in _STAGES if pattern.search(message)), None)


def count_of(message: str) -> tuple[int, int | None] | None:
    """(done, total) a message counts, ``(3, 12)`` of ``chunk 3 of 12``, ``(3, None)`` of
    ``iteration 3``; None when it counts nothing."""
    m = _COUNT.search(message)
    if m:
        done, total = (m.group(1), m.group(2)) if m.group(1) else (m.group(3), m.group(4))
        return int(done), int(total)
    m = _ITERATION.search(message)
    return (int(m.group(1)), None) if m else None


class Progress:
    """The ``say`` callback of a command (module docstring); a context manager that stops the
    live display. ``stream``: where it writes (stderr); ``live``: force the terminal display on
    or off (default: when ``stream`` is a terminal)."""

    def __init__(self, verbosity: int = NORMAL, stream: TextIO | None = None, live: bool | None = None):
        self.verbosity = verbosity
        self.stream = stream if stream is not None else sys.stderr
        self.live = (self.stream.isatty() if live is None else live) and verbosity > QUIET
        self._t0 = time.perf_counter()
        self._bars = None
        self._tasks: dict[str, int] = {}
        self._current: str | None = None

    def __call__(self, message: str) -> None:
        warning = message.lstrip().lower().startswith("warning")
        if self.verbosity <= QUIET and not warning:
            return
        line = f"[{time.perf_counter() - self._t0:7.1f} s] {message}" if self.verbosity >= VERBOSE else message
        if not self.live:
            print(line, file=self.stream, flush=True)
            return
        self._show(message, line)

    def _start(self):
        from rich.console import Console
        from rich.progress import (BarColumn, Progress as RichProgress, SpinnerColumn, TextColumn,
                                   TimeElapsedColumn, TimeRemainingColumn)
        self._bars = RichProgress(SpinnerColumn(), TextColumn("{task.description:<14}"), BarColumn(),
                                  TextColumn("{task.fields[count]}"), TimeElapsedColumn(),
                                  TextColumn("ETA"), TimeRemainingColumn(),
                                  console=Console(file=self.stream), transient=False)
        self._bars.start()

    def _show(self, message: str, line: str) -> None:
        if self._bars is None:
            self._start()
        bars = self._bars
        bars.console.print(line, markup=False, highlight=False)
        stage = stage_of(message)
        if stage is None:
            return
        if stage != self._current and self._current in self._tasks:
            task = self._tasks[self._current]
            if bars.tasks[task].total is None:  # an uncounted stage is done when another starts (a counted
                bars.update(task, total=1, completed=1)  # one, e.g. chunks, keeps its count: it may go on)
        self._current = stage
        if stage not in self._tasks:
            self._tasks[stage] = bars.add_task(stage, total=None, count="")
        task = self._tasks[stage]
        counted = count_of(message)
        if counted is not None:
            done, total = counted
            bars.update(task, completed=done, total=total,
                        count=f"{done}" + (f"/{total}" if total else ""))

    def close(self) -> None:
        """Stop the live display (the bars stay on the screen)."""
        if self._bars is not None:
            for task in self._tasks.values():
                t = self._bars.tasks[task]
                if not t.finished:
                    self._bars.update(task, total=t.total or 1, completed=t.total or 1)
            self._bars.stop()
            self._bars = None

    def __enter__(self) -> "Progress":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def plain(message: str) -> None:
    """Plain progress line on stderr (stdout stays machine-readable)."""
    print(message, file=sys.stderr, flush=True)


Say = Callable[[str], None]
