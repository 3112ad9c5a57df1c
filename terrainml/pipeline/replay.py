"""Served-path validation: held-out runs replayed through the online predictor.

Window scores say how often a window is named right; a robot is served by
:class:`~terrainml.stream.tick.predictor.Predictor`, which cuts its own windows online, fuses them,
ages them by distance and falls back when it has no fresh, confident class. A model whose
windows are good but which the online rules never let classify is useless on the robot, and no
window score shows it. So before ``train`` saves a model, the model of every outer fold (fitted
without that fold's runs) is saved as a model folder and loaded by the same
:meth:`Predictor.from_model_dir` that ``terrainml predict`` uses (with its classification lag),
and a course of the fold's held-out runs is replayed through it tick by tick.

:func:`make_course` puts a ``segment_s`` piece (from the middle) of each run end to end, classes
interleaved so the course changes terrain between pieces. :func:`replay_course` scores it:

* ``right_share``: share of moving labelled ticks served the labelled class (a fallback tick is
  never right); moving = the predictor's odometer advancing at >=
  :data:`~terrainml.stream.app.scoring.MOVING_TICK_MPS`, or, on an ``estimator_unhealthy`` tick
  (which the odometer does not count), the wheels' rim speed
  (:func:`~terrainml.stream.app.scoring.moving_ticks`), as in
  :func:`terrainml.stream.app.scoring.replay_summary`; ``right_share_settled`` leaves out
  ``settle_s`` after each label change;
* ``fallback_share``: share of moving labelled ticks served a fallback;
* ``classified_share``: share of moving labelled ticks served a class (1 - fallback share);
* ``classifications_per_m``: window classifications per metre travelled;
* ``median_change_m``: median distance from a label change to the first tick served the new
  class; ``changes_never_right``: changes whose piece ends before that.

A replay that classifies on fewer than :data:`MIN_CLASSIFIED_SHARE` of the moving ticks refuses
the model (:func:`replay_refusal`), unless the user overrides it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np
import pandas as pd

from terrainml.stream.tick.config import ServingConfig
from terrainml.stream.tick.predictor import Predictor
from terrainml.pipeline.train_options import MIN_CLASSIFIED_SHARE, REPLAY_SEGMENT_S
from terrainml.stream.app.options import CLASSIFY_LAG_TICKS
from terrainml.stream.app.scoring import replay_served, score_served
from terrainml.stream.app.tick_losses import pooled_tick_losses, tick_losses

__all__ = ["make_course", "replay_course", "replay_refusal", "pooled_replay", "REPLAY_SEGMENT_S",
           "MIN_CLASSIFIED_SHARE", "SETTLE_S", "ReplayRefused"]

#: seconds after a label change left out of ``right_share_settled``
SETTLE_S = 3.0


class ReplayRefused(RuntimeError):
    """The served replay of the held-out runs does not prove the model (reason in the message).

    ``report_dir``: the folder whose ``report.md`` shows the replay (no model saved in it).
    """

    def __init__(self, message: str, report_dir: str | Path | None = None):
        super().__init__(message)
        self.report_dir = None if report_dir is None else Path(report_dir)


def _rate_hz(df: pd.DataFrame) -> float:
    rate = (df.attrs.get("terrainml") or {}).get("rate_hz")
    return float(rate) if rate else float(1.0 / np.median(np.diff(df["t_s"].to_numpy())))


def _label(df: pd.DataFrame) -> int:
    lab = pd.to_numeric(df["terrain"], errors="coerce") if "terrain" in df.columns else pd.Series([], dtype=float)
    lab = lab[lab >= 0]
    return int(lab.mode().iloc[0]) if len(lab) else -1


def make_course(tables: Sequence[pd.DataFrame], run_ids: Sequence[str] | None = None,
                segment_s: float | None = REPLAY_SEGMENT_S, drop_columns: Sequence[str] = (),
                interleave: bool = True) -> pd.DataFrame:
    """One run of ``segment_s`` pieces (from the middle; None: whole runs) of the runs ``run_ids``.

    Parameters
    ----------
    tables : ingested run tables (canonical columns, ``t_s``, ``run_id``, per-row ``terrain``).
    run_ids : runs to use (default all), in this order unless ``interleave``.
    segment_s : s per run, or None for the whole run.
    drop_columns : columns removed, as if the robot had no such sensor.
    interleave : order the pieces round-robin over classes (so consecutive pieces differ).

    Returns
    -------
    DataFrame, time axis continuous (each piece follows the previous one by one tick), ``run_id``
    "course", the first table's metadata.
    """
    by_id = {str(df["run_id"].iloc[0]): df for df in tables if len(df)}
    ids = list(by_id) if run_ids is None else [str(r) for r in run_ids]
    missing = [r for r in ids if r not in by_id]
    if missing:
        raise ValueError(f"make_course: no table for runs {missing}")
    if interleave:
        per: dict[int, list[str]] = {}
        for r in ids:
            per.setdefault(_label(by_id[r]), []).append(r)
        queues = [list(v) for _, v in sorted(per.items())]
        ids = [q.pop(0) for _ in range(max(map(len, queues), default=0)) for q in queues if q]
    parts, t_next = [], 0.0
    for rid in ids:
        df = by_id[rid]
        rate = _rate_hz(df)
        n = len(df) if segment_s is None else int(round(segment_s * rate))
        start = max(0, (len(df) - n) // 2)
        part = df.iloc[start:start + n].copy()
        part["t_s"] = part["t_s"].to_numpy() - part["t_s"].iloc[0] + t_next
        t_next = float(part["t_s"].iloc[-1]) + 1.0 / rate
        parts.append(part)
    if not parts:
        raise ValueError("make_course: no runs")
    course = pd.concat(parts, ignore_index=True)
    course = course.drop(columns=[c for c in drop_columns if c in course.columns])
    course["run_id"] = "course"
    course.attrs = dict(tables[0].attrs)
    return course


def replay_course(model_dir: str | Path, course: pd.DataFrame, settle_s: float = SETTLE_S,
                  config: ServingConfig | None = None) -> dict[str, Any]:
    """Serve ``course`` tick by tick through ``Predictor.from_model_dir(model_dir)`` and score it
    (:func:`terrainml.stream.app.scoring.score_served`).

    ``config``: serving settings (default: those of ``terrainml predict``, classification
    :data:`~terrainml.stream.app.options.CLASSIFY_LAG_TICKS` ticks behind).

    Returns
    -------
    dict: ``ticks``, ``moving_ticks``, ``right_share``, ``right_share_settled``, ``fallback_share``,
    ``classified_share``, ``classifications``, ``distance_m``, ``classifications_per_m``,
    ``changes``, ``median_change_m``, ``changes_never_right``, ``fallback_reasons`` (counts
    over moving ticks), ``losses`` (where the moving ticks went:
    :func:`terrainml.stream.app.tick_losses.tick_losses`).
    """
    p = Predictor.from_model_dir(model_dir, config=config or ServingConfig(classify_lag_ticks=CLASSIFY_LAG_TICKS))
    cols = list(course.columns)
    ticks = replay_served(p, (dict(zip(cols, row)) for row in course.itertuples(index=False)))
    scores = score_served(ticks.t_s, ticks.label, ticks.served, ticks.odometer_m, ticks.reasons, settle_s,
                          ticks.stats, ticks.rim_speed_mps)
    scores["losses"] = tick_losses(ticks, settle_s)
    return scores


def pooled_replay(folds: Sequence[dict]) -> dict[str, Any]:
    """Tick-weighted figures over the folds' replays (``right_share``, ``fallback_share``,
    ``classified_share``; classifications per metre over the total distance; ``losses`` summed)."""
    n = sum(f["moving_ticks"] for f in folds)
    def w(k):
        return (float(sum(f[k] * f["moving_ticks"] for f in folds if f["moving_ticks"]) / n) if n
             else float("nan"))
    dist = sum(f["distance_m"] for f in folds)
    meds = [f["median_change_m"] for f in folds if np.isfinite(f["median_change_m"])]
    return {"moving_ticks": int(n), "right_share": w("right_share"), "fallback_share": w("fallback_share"),
            "classified_share": w("classified_share"),
            "classifications_per_m": float(sum(f["classifications"] for f in folds) / dist) if dist else float("nan"),
            "median_change_m": float(np.median(meds)) if meds else float("nan"),
            "changes": int(sum(f["changes"] for f in folds)),
            "changes_never_right": int(sum(f["changes_never_right"] for f in folds)),
            "losses": pooled_tick_losses([f["losses"] for f in folds if "losses" in f])}


def replay_refusal(pooled: dict, min_share: float = MIN_CLASSIFIED_SHARE) -> str:
    """Why the replay refuses the model ("" when it does not)."""
    n, share = pooled.get("moving_ticks", 0), pooled.get("classified_share", float("nan"))
    if n == 0:
        return "the replay of the held-out runs has no moving labelled tick, so the served path is unproven"
    if not share >= min_share:
        return (f"served replay of the held-out runs classifies on {share:.0%} of {n} moving ticks "
                f"(needs >= {min_share:.0%}): the online window rules reject the windows this model needs")
    return ""
