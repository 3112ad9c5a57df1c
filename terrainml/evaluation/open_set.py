"""Leave-one-class-out (open-set) evaluation of the novelty score.

Each class in turn plays the unknown: for every outer grouped fold (the same folds as the
closed-set cross-validation), an :class:`~terrainml.models.novelty.OpenSetModel` is fitted on
the fold's training windows *without* that class (its threshold set in inner grouped folds of
them only) and scores the fold's test windows. The test part holds runs of the known classes
that the model never saw (their flagged share is the false-alarm rate) and runs of the unknown
class (its flagged share is the detection rate); over the folds every window is scored once.
The engine is :func:`terrainml.evaluation.cv.cross_validate`, run once per held-out class.

Per held-out class (:func:`leave_one_class_out`): AUROC of the novelty score (unknown windows
against the known classes' held-out windows), on all windows and on *moving* windows
(:func:`moving_windows`: mean wheel rim speed above ``MOVING_MPS``, the line of the served
course scores; a robot standing still feels the same on any ground); the share of the unknown
class's windows flagged at the chosen threshold; the share of the known classes' held-out
windows flagged (false alarms); the known classes' balanced accuracy of the same models; and the
*reach* of the score (:func:`flagged_at_false_alarm`): the share of the unknown's moving windows
that the one threshold flagging :data:`REACH_FALSE_ALARM` of the known held-out windows would
flag. That threshold is read off the evaluated windows themselves, so it is an upper bound for any
threshold of this score (the point of its ROC curve at the issue's false-alarm line), never a
deployable setting: it tells a score that cannot separate the unknown (low reach) from a threshold
that is merely cautious (reach far above the flagged share).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np
import pandas as pd
from sklearn.metrics import balanced_accuracy_score, roc_auc_score

from terrainml.evaluation.cv import Scoring, cross_validate
from terrainml.models.novelty import (
    DEFAULT_FALSE_ALARM,
    DEFAULT_K,
    DEFAULT_METHOD,
    MOVING_MPS,
    OpenSetModel,
    moving_mask,
    moving_windows,
)

__all__ = ["leave_one_class_out", "NoveltySettings", "OpenSetResult", "open_set_markdown", "flagged_at_false_alarm",
           "REACH_FALSE_ALARM"]

#: the false-alarm line at which the score's reach is read (share of known windows)
REACH_FALSE_ALARM = 0.05


@dataclass
class OpenSetResult:
    """Leave-one-class-out results.

    Attributes
    ----------
    table : DataFrame, one row per held-out class: ``unknown``, ``n_unknown``, ``n_known``,
        ``auroc``, ``auroc_moving``, ``unknown_flagged`` (share of the unknown's moving windows
        flagged), ``unknown_flagged_all`` (all its windows), ``false_alarm`` (share of the known
        classes' held-out windows flagged), ``false_alarm_moving``, ``known_balanced_accuracy``,
        ``unknown_flagged_reach`` (share of the unknown's moving windows over the threshold that
        flags :data:`REACH_FALSE_ALARM` of the known held-out windows, read off them: an upper bound).
    scores : {class name: ndarray (n,)} out-of-fold novelty scores of every window (NaN: never tested).
    flagged : {class name: ndarray (n,) bool}.
    settings : dict (method, k, false-alarm target, inner folds, folds, seed, reach false alarm).
    windows : DataFrame (n rows, window order): ``run``, ``label`` (class name), ``moving``.
    """

    table: pd.DataFrame
    scores: dict = field(default_factory=dict)
    flagged: dict = field(default_factory=dict)
    settings: dict = field(default_factory=dict)
    windows: pd.DataFrame | None = None

    def means(self) -> dict:
        """Unweighted means over the held-out classes of the table's figures."""
        cols = ["auroc", "auroc_moving", "unknown_flagged", "unknown_flagged_all", "false_alarm",
                "false_alarm_moving", "known_balanced_accuracy", "unknown_flagged_reach"]
        return {c: float(self.table[c].mean()) for c in cols}

    def to_dict(self) -> dict:
        return {"per_class": self.table.to_dict(orient="records"), "mean": self.means(),
                "settings": self.settings}

    def window_table(self) -> pd.DataFrame:
        """One row per window: run, label, moving, and per held-out class C ``score_without_C``
        and ``flagged_without_C`` (what ``evaluate --open-set`` writes for a closer look)."""
        cols = {} if self.windows is None else {c: self.windows[c].to_numpy() for c in self.windows.columns}
        for name, sc in self.scores.items():
            cols[f"score_without_{name}"] = np.asarray(sc, dtype=np.float64)
            cols[f"flagged_without_{name}"] = np.asarray(self.flagged[name], dtype=bool)
        return pd.DataFrame(cols)


def _auroc(labels: np.ndarray, scores: np.ndarray) -> float:
    return float(roc_auc_score(labels, scores)) if 0 < labels.sum() < len(labels) else float("nan")


def _share(mask: np.ndarray) -> float:
    return float(mask.mean()) if len(mask) else float("nan")


def flagged_at_false_alarm(known: np.ndarray, unknown: np.ndarray, false_alarm: float = REACH_FALSE_ALARM) -> float:
    """Share of ``unknown`` scores over the lowest threshold that flags at most ``false_alarm`` of
    ``known`` scores (a window is flagged when its score is strictly above the threshold).

    The threshold is the smallest known score with at most ``false_alarm * len(known)`` known
    scores above it. Read off the evaluated windows, it is the best any threshold of the score can
    do at that false-alarm share: an upper bound, not a setting (thresholds are set in inner folds).
    NaN when either side is empty.
    """
    known, unknown = np.sort(np.asarray(known, dtype=np.float64)), np.asarray(unknown, dtype=np.float64)
    if not len(known) or not len(unknown):
        return float("nan")
    allowed = int(np.floor(float(false_alarm) * len(known)))  # known scores that may lie above
    threshold = known[len(known) - 1 - allowed]
    return float((unknown > threshold).mean())


@dataclass(frozen=True)
class NoveltySettings:
    """The novelty score's settings (:func:`~terrainml.models.novelty.fit_novelty`): scorer
    ``method`` and ``k``, the threshold's target ``novelty_false_alarm`` (share of moving known
    windows over it) and its ``inner_folds`` (None: one run out at a time)."""

    method: str = DEFAULT_METHOD
    k: int = DEFAULT_K
    novelty_false_alarm: float = DEFAULT_FALSE_ALARM
    inner_folds: int | None = None


def leave_one_class_out(factory: Callable[[], Any], W, *, folds, classes: Sequence, class_names: Sequence[str],
                        moving: np.ndarray | None = None, novelty: NoveltySettings | None = None, seed: int = 0,
                        n_jobs: int | None = 1, progress: Callable[[str], None] | None = None) -> OpenSetResult:
    """Each class held out of training in turn, scored as the unknown.

    Parameters
    ----------
    factory : callable returning an unfitted classifier with a feature space (svm, hgb, an
        average of them).
    W : Windows (labels ``W.y``, runs ``W.groups``).
    folds : outer (train_idx, test_idx) grouped by run (:func:`~terrainml.evaluation.folds.grouped_folds`).
    classes : class ids, names ``class_names`` (same order).
    moving : bool (n,), the moving windows (default :func:`moving_windows`).
    novelty : :class:`NoveltySettings` (None: the defaults).
    seed : seed of the inner folds. n_jobs : joblib jobs over folds.
    progress : callback with a short message per held-out class.

    Returns
    -------
    OpenSetResult
    """
    nov = novelty or NoveltySettings()
    y, groups = W.y, W.groups
    gate = moving_mask(W)  # what OpenSetModel gates on (the same windows' wheel speeds)
    if moving is None:  # the gate is the default moving mask; without speed channels, say so
        moving = gate if gate is not None else moving_windows(W)
    moving = np.asarray(moving, dtype=bool)
    rows, scores, flagged = [], {}, {}
    for u, name in zip(classes, class_names):
        if progress:
            progress(f"open set: {name} held out as the unknown")
        folds_u = [(tr[y[tr] != u], te) for tr, te in folds]
        res = cross_validate(lambda: OpenSetModel(factory(), method=nov.method, k=nov.k,
                                                  novelty_false_alarm=nov.novelty_false_alarm,
                                                  inner_folds=nov.inner_folds, random_state=seed),
                             W, y, groups, folds=folds_u, n_jobs=n_jobs,
                             scoring=Scoring(classes, class_names, name=f"without {name}"))
        done = res.fold_of >= 0
        thr = np.array([m["novelty_threshold"] for m in res.fold_metrics])
        flag = np.zeros(len(y), dtype=bool)
        flag[done] = res.novelty[done] > thr[res.fold_of[done]]
        if gate is not None:  # the models judge moving windows only (their scorers' gate)
            flag &= gate
        unk, known = done & (y == u), done & (y != u)
        # a window the gate never flags counts below every threshold (the reach of what can be flagged)
        judged = res.novelty if gate is None else np.where(gate, res.novelty, -np.inf)
        rows.append({
            "unknown": name, "n_unknown": int(unk.sum()), "n_unknown_moving": int((unk & moving).sum()),
            "n_known": int(known.sum()),
            "auroc": _auroc(unk[done], res.novelty[done]),
            "auroc_moving": _auroc(unk[done & moving], res.novelty[done & moving]),
            "unknown_flagged": _share(flag[unk & moving]), "unknown_flagged_all": _share(flag[unk]),
            "false_alarm": _share(flag[known]), "false_alarm_moving": _share(flag[known & moving]),
            "known_balanced_accuracy": float(balanced_accuracy_score(y[known], res.y_pred[known])),
            "unknown_flagged_reach": flagged_at_false_alarm(judged[known], judged[unk & moving]),
        })
        scores[name], flagged[name] = np.where(done, res.novelty, np.nan), flag
    settings = {"method": nov.method, "k": int(nov.k), "false_alarm_target": float(nov.novelty_false_alarm),
                "inner_folds": "one run out" if nov.inner_folds is None else int(nov.inner_folds),
                "folds": len(folds),
                "seed": int(seed),
                "moving_mps": MOVING_MPS, "reach_false_alarm": REACH_FALSE_ALARM}
    names = dict(zip(classes, class_names))
    windows = pd.DataFrame({"run": np.asarray(groups).astype(str), "label": [names.get(c, str(c)) for c in y],
                            "moving": moving})
    return OpenSetResult(pd.DataFrame(rows), scores, flagged, settings, windows)


def open_set_markdown(result: OpenSetResult) -> list[str]:
    """Markdown lines of the leave-one-class-out table (percent), with the mean row."""
    pct = lambda x: f"{100 * x:.1f}" if np.isfinite(x) else "n/a"  # noqa: E731
    reach = f"reach: flagged % at {100 * REACH_FALSE_ALARM:.0f} % false alarms (upper bound)"
    header = ["unknown class", "windows (moving)", "AUROC", "AUROC moving", "unknown flagged % (moving)",
              "false alarms % (known held-out)", "known bal. acc. %", reach]
    rows = [[r.unknown, f"{r.n_unknown} ({r.n_unknown_moving})", f"{r.auroc:.3f}", f"{r.auroc_moving:.3f}",
             pct(r.unknown_flagged), pct(r.false_alarm), pct(r.known_balanced_accuracy),
             pct(r.unknown_flagged_reach)]
            for r in result.table.itertuples()]
    m = result.means()
    rows.append(["**mean**", "", f"**{m['auroc']:.3f}**", f"**{m['auroc_moving']:.3f}**",
                 pct(m["unknown_flagged"]), pct(m["false_alarm"]), pct(m["known_balanced_accuracy"]),
                 pct(m["unknown_flagged_reach"])])
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return out + ["| " + " | ".join(map(str, r)) + " |" for r in rows]
