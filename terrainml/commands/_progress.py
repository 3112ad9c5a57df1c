"""The CLI's rendering of the pipelines' progress (:class:`terrainml.pipeline.progress.Step`).

On a terminal, a live rich display: one row per stage with its bar, ``k/n`` units, elapsed time
and rich's estimate of the time left (the spinner and the clock refresh continuously, so the
screen is never still while work runs); finished stages stay on screen. Off a terminal (a CI
log, a pipe), plain lines: one when a stage starts, then one per unit done at most every
:data:`LINE_INTERVAL_S` seconds, and always the last (``n/n``), each with the elapsed time and
the estimate of the time left. Warnings and notes (texts starting ``warning:`` or ``note:``) are
printed in both modes; other texts only describe the current stage on the live display.
"""

from __future__ import annotations

import time
from datetime import timedelta
from typing import Any, Callable

from terrainml.pipeline.progress import Step

__all__ = ["StageReporter", "LINE_INTERVAL_S"]

#: off a terminal, at most one line per this many seconds within a stage (besides its first and last)
LINE_INTERVAL_S = 1.0


def _clock_text(seconds: float | None) -> str:
    return "-:--:--" if seconds is None else str(timedelta(seconds=max(0, int(round(seconds)))))


class StageReporter:
    """A progress callback for the pipelines that renders their :class:`Step` s with rich.

    Use as a context manager; the object is the callback (``progress=reporter``).

    Parameters
    ----------
    console : rich Console (``console.is_terminal`` picks the live display or plain lines).
    label : the command's name, first on every line (``"train"``).
    quiet : show nothing but warnings.
    clock : seconds now (default ``time.monotonic``); also rich's clock, so the estimate of the
        time left is rich's (:attr:`rich.progress.Task.time_remaining`) in both modes.
    line_interval_s : see :data:`LINE_INTERVAL_S`.
    """

    def __init__(self, console: Any, *, label: str = "train", quiet: bool = False,
                 clock: Callable[[], float] | None = None, line_interval_s: float = LINE_INTERVAL_S):
        self.console = console
        self.label = label
        self.quiet = quiet
        self.clock = clock or time.monotonic
        self.line_interval_s = line_interval_s
        self.live = bool(console.is_terminal) and not quiet
        self._progress: Any = None
        self._task: Any = None
        self._stage = ""
        self._last_line = float("-inf")
        self._last_text = ""

    def __enter__(self) -> "StageReporter":
        from rich.progress import (BarColumn, MofNCompleteColumn, Progress, SpinnerColumn, TextColumn,
                                   TimeElapsedColumn, TimeRemainingColumn)

        self._progress = Progress(SpinnerColumn(), TextColumn(f"[bold]{self.label}[/] {{task.fields[stage]}}"),
                                  BarColumn(), MofNCompleteColumn(), TextColumn("{task.fields[unit]}"),
                                  TimeElapsedColumn(), TextColumn("left"), TimeRemainingColumn(),
                                  TextColumn("{task.description}"), console=self.console, disable=not self.live,
                                  get_time=self.clock)
        self._progress.__enter__()
        return self

    def __exit__(self, *exc) -> None:
        if self._task is not None:
            self._progress.stop_task(self._task)
        self._progress.__exit__(*exc)

    # the callback ---------------------------------------------------------------------------
    def __call__(self, item: str | Step) -> None:
        if isinstance(item, Step):
            self.step(item)
        else:
            self.message(str(item))

    def message(self, msg: str) -> None:
        """A text: printed when a warning or a note, else the live display's description."""
        for tag, style in (("warning:", "yellow"), ("note:", "cyan")):
            if msg.startswith(tag):
                self.console.print(f"[{style}]{tag}[/]{msg[len(tag):]}", highlight=False)
                return
        if self._task is not None:
            self._progress.update(self._task, description=msg)

    def step(self, ev: Step) -> None:
        """A stage's progress: a new row (and line) when the stage changes, else its counts."""
        if ev.stage != self._stage:
            self._start(ev)
            return
        self._progress.update(self._task, completed=ev.done, total=ev.total, description=ev.detail)
        self._maybe_line(ev.done == ev.total, ev.detail)

    def nested(self) -> Callable[[str | Step], None]:
        """A callback for work nested in the current stage (a member's own training): its
        Steps and texts describe the current stage's row; only warnings are printed."""
        def inner(item: str | Step) -> None:
            text = str(item)
            if text.startswith(("warning:", "note:")):
                self.message(text)
                return
            if self._task is not None:
                self._progress.update(self._task, description=text)
                self._maybe_line(False, text)
        return inner

    # rendering --------------------------------------------------------------------------------
    def _start(self, ev: Step) -> None:
        if self._task is not None:
            self._progress.stop_task(self._task)
        self._stage = ev.stage
        self._task = self._progress.add_task(ev.detail, total=ev.total, completed=ev.done, stage=ev.stage,
                                             unit=ev.unit)
        self._maybe_line(True, ev.detail)

    def _maybe_line(self, force: bool, detail: str) -> None:
        """Off a terminal: a plain line, at most every ``line_interval_s`` unless ``force``."""
        if self.live or self.quiet:
            return
        now = self.clock()
        if not force and now - self._last_line < self.line_interval_s:
            return
        text = self.line(detail)
        if text != self._last_text:  # e.g. a stage of zero units: its start is its end
            self._last_line, self._last_text = now, text
            self.console.print(text, highlight=False, markup=False, soft_wrap=True)

    def line(self, detail: str = "") -> str:
        """The plain line of the current stage: counts, elapsed time and the time left."""
        task = self._progress.tasks[-1] if self._progress.tasks else None
        if task is None:
            return f"{self.label}:"
        f = task.fields
        total = None if task.total is None else int(task.total)
        count = f" {int(task.completed)}/{total} {f['unit']}".rstrip() if total is not None else ""
        left = (f", about {_clock_text(task.time_remaining)} left"
                if total is not None and task.time_remaining is not None and task.completed < total else "")
        return (f"{self.label}: {f['stage']}{count}" + (f" ({detail})" if detail else "")
                + f"; {_clock_text(task.elapsed)} elapsed{left}")
