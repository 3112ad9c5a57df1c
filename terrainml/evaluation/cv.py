"""Grouped, seeded cross-validation (SYSTEM §9): no run is ever split across folds.

:func:`grouped_folds` is ``StratifiedGroupKFold(n_splits, shuffle=True, random_state=seed)``
over the windows' run ids; the same seed gives the same folds. :func:`cross_validate` fits a
fresh model (from a factory) on every training part, passing the run ids as ``groups`` so the
model's own inner search (nested CV) and early stopping stay grouped too, and predicts the
held-out runs. Folds run through joblib (``n_jobs``; inside ``joblib.parallel_config(backend=
"dask")`` they run on a Dask cluster), results in fold order.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
import pandas as pd
from joblib import Parallel, delayed
from sklearn.model_selection import StratifiedGroupKFold

from terrainml.evaluation.metrics import classification_metrics, summarise_folds

__all__ = ["grouped_folds", "cross_validate", "CVResult", "check_no_shared_runs"]


def grouped_folds(y, groups, n_splits: int = 5, seed: int = 0) -> list[tuple[np.ndarray, np.ndarray]]:
    """Stratified folds grouped by run, seeded.

    Parameters
    ----------
    y : array (n,), labels.
    groups : array (n,), run ids.
    n_splits : int >= 2 (lowered to the number of runs when there are fewer, with a floor of 2).
    seed : int.

    Returns
    -------
    list of (train_idx, test_idx) int arrays.
    """
    y = np.asarray(y)
    groups = np.asarray(groups)
    n_runs = len(np.unique(groups))
    if n_runs < 2:
        raise ValueError(f"grouped CV needs at least 2 runs, got {n_runs}")
    k = int(min(n_splits, n_runs))
    if k < 2:
        raise ValueError("n_splits must be >= 2")
    cv = StratifiedGroupKFold(n_splits=k, shuffle=True, random_state=int(seed))
    return [(np.asarray(tr), np.asarray(te)) for tr, te in cv.split(np.zeros(len(y)), y, groups)]


def check_no_shared_runs(folds, groups) -> None:
    """Raise AssertionError when a run appears in the test part of two folds or in train and test."""
    groups = np.asarray(groups)
    seen: dict[Any, int] = {}
    for k, (tr, te) in enumerate(folds):
        test_runs = set(groups[te].tolist())
        if test_runs & set(groups[tr].tolist()):
            raise AssertionError(f"fold {k}: runs in both train and test")
        for r in test_runs:
            if r in seen:
                raise AssertionError(f"run {r!r} in the test parts of folds {seen[r]} and {k}")
            seen[r] = k


@dataclass
class CVResult:
    """Out-of-fold results of one model.

    Attributes
    ----------
    folds : list of (train_idx, test_idx).
    fold_of : ndarray (n,), fold index that predicted each window.
    y_true, y_pred : ndarray (n,).
    proba : ndarray (n, K), columns in ``classes`` order.
    classes : ndarray (K,).
    fold_metrics : list of dict (classification_metrics per fold, plus fit/predict times).
    summary : dict metric -> {mean, std} over folds.
    pooled : dict, metrics of all out-of-fold predictions together.
    """

    folds: list
    fold_of: np.ndarray
    y_true: np.ndarray
    y_pred: np.ndarray
    proba: np.ndarray
    classes: np.ndarray
    fold_metrics: list = field(default_factory=list)
    summary: dict = field(default_factory=dict)
    pooled: dict = field(default_factory=dict)

    def per_fold_frame(self) -> pd.DataFrame:
        keys = ("n_windows", "accuracy", "balanced_accuracy", "macro_f1", "adjacent_accuracy", "ece",
                "desired_slip_error_mean", "fit_time_s", "predict_time_s", "n_test_runs")
        rows = [{"fold": k, **{c: m.get(c, np.nan) for c in keys}} for k, m in enumerate(self.fold_metrics)]
        return pd.DataFrame(rows)


def _run_fold(factory: Callable[[], Any], X, y, groups, tr, te, fit_kwargs: dict):
    model = factory()
    Xtr = X.subset(tr) if hasattr(X, "subset") else np.asarray(X)[tr]
    Xte = X.subset(te) if hasattr(X, "subset") else np.asarray(X)[te]
    t0 = time.perf_counter()
    model.fit(Xtr, y[tr], groups=groups[tr], **fit_kwargs)
    t1 = time.perf_counter()
    proba = np.asarray(model.predict_proba(Xte), dtype=float)
    t2 = time.perf_counter()
    return np.asarray(model.classes_), proba, t1 - t0, t2 - t1


def cross_validate(factory: Callable[[], Any], X, y, groups, *, n_splits: int = 5, seed: int = 0,
                   n_jobs: int | None = 1, table: Any = None, classes=None,
                   fit_kwargs: dict | None = None, folds=None) -> CVResult:
    """Grouped K-fold CV of a model factory on raw windows.

    Parameters
    ----------
    factory : callable returning an unfitted classifier with ``fit(X, y, groups=...)``,
        ``predict_proba`` and ``classes_``.
    X : Windows or ndarray (n, C, T).
    y : array (n,), labels. groups : array (n,), run ids.
    n_splits, seed : folds (see :func:`grouped_folds`).
    n_jobs : joblib jobs over folds.
    table : desired-slip table for the desired-slip error (or None).
    classes : all classes in physical order (default: sorted labels of y).
    folds : precomputed folds (overrides n_splits/seed).

    Returns
    -------
    CVResult
    """
    y = np.asarray(y)
    groups = np.asarray(groups)
    folds = folds if folds is not None else grouped_folds(y, groups, n_splits, seed)
    check_no_shared_runs(folds, groups)
    classes = np.asarray(classes) if classes is not None else np.unique(y)
    results = Parallel(n_jobs=n_jobs)(
        delayed(_run_fold)(factory, X, y, groups, tr, te, fit_kwargs or {}) for tr, te in folds)
    n, K = len(y), len(classes)
    proba = np.zeros((n, K))
    y_pred = np.empty(n, dtype=y.dtype)
    fold_of = np.full(n, -1, dtype=np.int64)
    fold_metrics = []
    col = {c: k for k, c in enumerate(classes.tolist())}
    for k, ((tr, te), (cls_k, p, fit_s, pred_s)) in enumerate(zip(folds, results)):
        pk = np.zeros((len(te), K))
        for j, c in enumerate(cls_k.tolist()):
            pk[:, col[c]] = p[:, j]
        proba[te] = pk
        y_pred[te] = classes[np.argmax(pk, axis=1)]
        fold_of[te] = k
        m = classification_metrics(y[te], y_pred[te], pk, classes, table)
        m.update({"fit_time_s": float(fit_s), "predict_time_s": float(pred_s),
                  "n_test_runs": int(len(np.unique(groups[te])))})
        fold_metrics.append(m)
    res = CVResult(folds, fold_of, y, y_pred, proba, classes, fold_metrics)
    res.summary = summarise_folds(fold_metrics)
    res.pooled = classification_metrics(y, y_pred, proba, classes, table)
    return res
