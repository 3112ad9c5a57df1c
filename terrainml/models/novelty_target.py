"""The novelty threshold's false-alarm target: its default and its range, in plain Python.

:mod:`terrainml.models.novelty` sets the threshold with it; the CLI offers it as
``--novelty-false-alarm`` and shows the default in ``--help``. Kept apart from the scorer (numpy,
sklearn) so that ``terrainml --help`` imports neither.
"""

from __future__ import annotations

__all__ = ["DEFAULT_FALSE_ALARM", "check_false_alarm"]

#: target share of moving known-ground windows flagged: the 5 % line the unknown-ground
#: requirement sets. Chosen on the simulator's tuning runs (seed 7, not the evaluation's seed 0),
#: where one run out realises 1.7 % of moving known windows for it (1.2 % for a 3 % target; three
#: inner folds would realise about a third of the target). It costs known ground served at
#: changes of terrain (tuning courses: 88.6 % served right, against 91.4 % at a 3 % target; the
#: safe cap costs no open-set mission): docs/models.md, "Unknown ground"
DEFAULT_FALSE_ALARM = 0.05


def check_false_alarm(novelty_false_alarm: float) -> float:
    """The threshold's false-alarm target as a float; ValueError unless it is in (0, 0.5)."""
    v = float(novelty_false_alarm)
    if not 0.0 < v < 0.5:
        raise ValueError(f"novelty false-alarm target must be in (0, 0.5) (a share of moving known windows, "
                         f"e.g. 0.05), got {novelty_false_alarm}")
    return v
