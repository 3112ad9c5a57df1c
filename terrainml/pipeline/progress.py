"""Typed progress of the long pipelines (``train``): which stage, how far, of how many.

The training pipelines (:mod:`terrainml.pipeline.autotrain`, :mod:`terrainml.pipeline.select`,
:mod:`terrainml.pipeline.train`) take one ``progress`` callback. It receives either a short text
(a note or a ``"warning: ..."``) or a :class:`Step`: the stage now running (:data:`STAGES`), the
units done and the units planned (``total``; None when unknown). A Step reads as text too
(``str(step)``), so a callback that only prints messages still works. The command line renders
the Steps (:mod:`terrainml.commands._progress`: a live display on a terminal, one line per stage
and a line per few fits off a terminal).

This module imports nothing heavy: the CLI imports it before any long work.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Union

__all__ = ["Step", "STAGES", "ProgressFn", "report"]

#: stage names, in the order ``train`` runs them (a run uses those it needs)
STAGES = ("logs", "windows", "selection", "cross-validation", "served replay", "final fit", "ablation",
          "open set", "members")


@dataclass(frozen=True)
class Step:
    """How far a stage is.

    Attributes
    ----------
    stage : one of :data:`STAGES`.
    done : units finished (0 when the stage starts).
    total : units planned, or None when unknown; it may grow or shrink while the stage runs
        (the selection's screening decides how many fits follow).
    unit : what a unit is, plural (``"fits"``, ``"folds"``, ``"specs"``).
    detail : what runs now (e.g. ``"short/svm"``), or "".
    """

    stage: str
    done: int
    total: int | None = None
    unit: str = ""
    detail: str = ""

    def __str__(self) -> str:
        count = f" {self.done}/{self.total}" if self.total is not None else ""
        unit = f" {self.unit}" if self.unit and count else ""
        return f"{self.stage}{count}{unit}" + (f" ({self.detail})" if self.detail else "")


#: the callback type of the pipelines' ``progress`` argument
ProgressFn = Callable[[Union[str, Step]], None]


def report(progress: ProgressFn | None, stage: str, done: int, total: int | None = None, unit: str = "",
           detail: str = "") -> None:
    """Send a :class:`Step` to ``progress`` (nothing when it is None)."""
    if progress is not None:
        progress(Step(stage, int(done), None if total is None else int(total), unit, detail))
