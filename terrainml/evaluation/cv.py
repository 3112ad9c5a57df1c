"""Cross-validation of a model factory on raw windows (design §9): one engine, one result.

:func:`cross_validate` fits a fresh model (from a factory) on the training part of every fold
and predicts the held-out windows. The folds come from a strategy of
:mod:`terrainml.evaluation.folds` (e.g. grouped by run, seeded) and are checked never to
split a group; the same ``groups`` go to the model's ``fit``, so its own inner search (nested
CV) and early stopping split by them too and hyper-parameters are never tuned on a test fold.
Folds run through joblib (``n_jobs``; inside ``joblib.parallel_config(backend="dask")`` they run
on a Dask cluster), results in fold order.

:class:`CVResult` holds the out-of-fold predictions and probabilities, per-fold and pooled
metrics; :func:`average_results` is the fixed-rule ensemble of several results (the mean of
their out-of-fold probabilities, e.g. ``svm+hgb``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np
import pandas as pd
from joblib import Parallel, delayed

from terrainml.evaluation.folds import check_groups_not_split
from terrainml.evaluation.metrics import classification_metrics, is_ordered, summarise_folds

__all__ = ["cross_validate", "Scoring", "CVResult", "average_results", "predict_held_out", "assemble_result"]

#: columns of :meth:`CVResult.per_fold_frame`
FOLD_COLUMNS = ("n_windows", "accuracy", "balanced_accuracy", "macro_f1", "adjacent_accuracy", "ece",
                "desired_slip_error_mean", "fit_time_s", "predict_time_s", "n_test_groups")


@dataclass
class CVResult:
    """Out-of-fold results of one model.

    Attributes
    ----------
    folds : list of (train_idx, test_idx).
    fold_of : ndarray (n,), fold index that predicted each window (-1: in no test part).
    y_true, y_pred : ndarray (n,).
    proba : ndarray (n, K) or None, out-of-fold probabilities with columns in ``classes`` order
        (None when the model has no ``predict_proba``; otherwise ``y_pred`` is their argmax).
    classes : ndarray (K,). class_names : list (K,), names of ``classes``.
    fold_metrics : list of dict, per fold :func:`~terrainml.evaluation.metrics.
        classification_metrics` plus ``fold``, ``fit_time_s``, ``predict_time_s``,
        ``n_test_groups`` and ``best_params`` (the model's inner-search choice, if any).
    summary : dict metric -> {mean, std} over folds.
    pooled : dict, metrics of all out-of-fold predictions together (confusion matrix with rows
        true and columns predicted, recall per class, ...).
    name : label of the result (e.g. ``"(b) svm"``).
    novelty : ndarray (n,) or None, out-of-fold novelty scores of an open-set model (its
        threshold per fold is the fold metrics' ``novelty_threshold``); NaN outside the test parts.
    fold_models : list or None, every fold's fitted model (``cross_validate(keep_models=True)``).
    """

    folds: list
    fold_of: np.ndarray
    y_true: np.ndarray
    y_pred: np.ndarray
    proba: np.ndarray | None
    classes: np.ndarray
    class_names: list = field(default_factory=list)
    fold_metrics: list = field(default_factory=list)
    summary: dict = field(default_factory=dict)
    pooled: dict = field(default_factory=dict)
    name: str = ""
    novelty: np.ndarray | None = None
    fold_models: list | None = None

    @property
    def accuracy(self) -> float:
        return float(self.pooled["accuracy"])

    @property
    def balanced_accuracy(self) -> float:
        return float(self.pooled["balanced_accuracy"])

    def recall_per_class(self) -> dict[str, float]:
        """Pooled recall per class name (NaN for a class with no test window)."""
        rec = self.pooled["recall_per_class"]
        return {n: float(rec.get(str(c), np.nan)) for c, n in zip(self.classes.tolist(), self.class_names)}

    def confusion_frame(self) -> pd.DataFrame:
        """Pooled confusion matrix (windows), rows true and columns predicted, by class name."""
        return pd.DataFrame(self.pooled["confusion_matrix"], index=self.class_names, columns=self.class_names)

    def per_fold_frame(self) -> pd.DataFrame:
        rows = [{"fold": k, **{c: m.get(c, np.nan) for c in FOLD_COLUMNS}} for k, m in enumerate(self.fold_metrics)]
        return pd.DataFrame(rows)


def _subset(X, idx):
    return X.subset(idx) if hasattr(X, "subset") else np.asarray(X)[idx]


def _run_fold(factory: Callable[[], Any], X, y, groups, tr, te, keep_model: bool = False):
    """Fit on ``tr``, predict ``te``: (classes, proba or None, y_pred, fit s, predict s, best_params,
    (novelty scores, threshold) or None) plus the fitted model when ``keep_model``."""
    model = factory()
    Xtr, Xte = _subset(X, tr), _subset(X, te)
    t0 = time.perf_counter()
    model.fit(Xtr, y[tr], groups=groups[tr])
    t1 = time.perf_counter()
    if hasattr(model, "predict_proba") and hasattr(model, "classes_"):
        cls = np.asarray(model.classes_)
        proba = np.asarray(model.predict_proba(Xte), dtype=float)
        pred = cls[np.argmax(proba, axis=1)]
    else:  # e.g. the BorealTC authors' SVM recipe: labels only
        cls, proba, pred = None, None, np.asarray(model.predict(Xte))
    t2 = time.perf_counter()
    nov = None
    if hasattr(model, "novelty_score"):  # an open-set model (terrainml.models.novelty.OpenSetModel)
        nov = (np.asarray(model.novelty_score(Xte), dtype=float), float(model.novelty_threshold_))
    out = (cls, proba, pred, t1 - t0, t2 - t1, dict(getattr(model, "best_params_", {}) or {}), nov)
    return (*out, model) if keep_model else out


def _assemble(folds, y, classes, class_names, y_pred, proba, fold_info: Sequence[dict], table,
              name) -> CVResult:
    """Per-fold and pooled metrics of out-of-fold predictions (windows in no test part skipped);
    ``fold_info`` holds per fold the entries added to its metrics (times, groups, parameters)."""
    fold_of = np.full(len(y), -1, dtype=np.int64)
    fold_metrics = []
    ordered = is_ordered(class_names)  # adjacent-class accuracy only for an ordered class set
    for k, (_, te) in enumerate(folds):
        fold_of[te] = k
        m = classification_metrics(y[te], y_pred[te], None if proba is None else proba[te], classes, table,
                                   ordered=ordered)
        fold_metrics.append({**m, "fold": k, **fold_info[k]})
    done = fold_of >= 0
    pooled = classification_metrics(y[done], y_pred[done], None if proba is None else proba[done], classes, table,
                                     ordered=ordered)
    names = list(class_names) if class_names is not None else [str(c) for c in classes.tolist()]
    return CVResult(list(folds), fold_of, y, y_pred, proba, classes, names, fold_metrics,
                    summarise_folds(fold_metrics), pooled, name)


@dataclass(frozen=True)
class Scoring:
    """How :func:`cross_validate` scores and labels the held-out predictions.

    Attributes
    ----------
    classes : all classes in physical order (None: the sorted labels of y).
    class_names : names of ``classes`` (None: the labels as text).
    table : desired-slip table for the desired-slip error (or None).
    name : label stored in the result.
    """

    classes: Sequence | None = None
    class_names: Sequence[str] | None = None
    table: Any = None
    name: str = ""


def cross_validate(factory: Callable[[], Any], X, y, groups, *, folds, scoring: Scoring | None = None,
                   n_jobs: int | None = 1, progress: Callable[[int, int], None] | None = None,
                   keep_models: bool = False) -> CVResult:
    """K-fold CV of a model factory on raw windows; no group is ever split.

    Parameters
    ----------
    factory : callable returning an unfitted classifier with ``fit(X, y, groups=...)`` and
        ``predict_proba`` + ``classes_`` (or only ``predict``: then ``proba`` is None).
    X : Windows or ndarray (n, C, T).
    y : array (n,), labels.
    groups : array (n,), groups no fold may split and the model's inner search splits by
        (run ids; chunk ids for :func:`~terrainml.evaluation.folds.chunk_folds`).
    folds : list of (train_idx, test_idx) from a strategy of :mod:`terrainml.evaluation.folds`,
        e.g. ``grouped_folds(y, groups, k, seed)``.
    scoring : :class:`Scoring` (classes, their names, desired-slip table, label); None: defaults.
    n_jobs : joblib jobs over folds.
    progress : callback ``(folds done, n folds)`` after each fold, in fold order.
    keep_models : keep every fold's fitted model in the result's ``fold_models`` (fold order),
        e.g. to serve it on the fold's held-out runs (:mod:`terrainml.pipeline.replay`).

    Returns
    -------
    CVResult
    """
    sc = scoring or Scoring()
    y = np.asarray(y)
    groups = np.asarray(groups)
    check_groups_not_split(folds, groups)
    classes = np.asarray(sc.classes) if sc.classes is not None else np.unique(y)
    jobs = (delayed(_run_fold)(factory, X, y, groups, tr, te, keep_models) for tr, te in folds)
    if progress is None:
        results = Parallel(n_jobs=n_jobs)(jobs)
    else:  # a generator, to report every fold as it completes
        results = []
        for r in Parallel(n_jobs=n_jobs, return_as="generator")(jobs):
            results.append(r)
            progress(len(results), len(folds))
    fold_models = [r[-1] for r in results] if keep_models else None
    results = [r[:7] for r in results]
    K = len(classes)
    col = {c: k for k, c in enumerate(classes.tolist())}
    y_pred = np.empty(len(y), dtype=y.dtype)
    proba = np.zeros((len(y), K)) if all(r[1] is not None for r in results) else None
    novelty = np.full(len(y), np.nan) if all(r[6] is not None for r in results) else None
    for (_, te), (cls_k, p, pred, *_, nov) in zip(folds, results):
        y_pred[te] = pred
        if proba is not None:
            for j, c in enumerate(cls_k.tolist()):
                proba[te, col[c]] = p[:, j]
        if novelty is not None:
            novelty[te] = nov[0]
    info = [{"fit_time_s": float(fit_s), "predict_time_s": float(pred_s),
             "n_test_groups": int(len(np.unique(groups[te]))), "best_params": best,
             **({} if nov is None else {"novelty_threshold": nov[1]})}
            for (_, te), (*_, fit_s, pred_s, best, nov) in zip(folds, results)]
    res = _assemble(folds, y, classes, sc.class_names, y_pred, proba, info, sc.table, sc.name)
    res.novelty = novelty
    res.fold_models = fold_models
    return res


def predict_held_out(factory: Callable[[], Any], X, y, groups, splits, classes, *, n_jobs: int | None = 1,
                     progress: Callable[[int, int], None] | None = None, keep: Sequence[bool] | None = None
                     ) -> list[dict]:
    """Fit a fresh model on the training part of every split and predict its held-out part.

    Unlike :func:`cross_validate` the held-out parts of different splits may overlap (the
    nested selection of :mod:`terrainml.pipeline.select` fits one model per pair of held-out
    run groups); within one split no group is in both parts (checked).

    Parameters
    ----------
    factory, X, y, groups : as in :func:`cross_validate`.
    splits : list of (train_idx, test_idx).
    classes : all classes; the probabilities' columns (a class the training part lacks gets 0).
    n_jobs : joblib jobs over splits. progress : callback ``(splits done, n splits)``.
    keep : per split, whether to return the fitted model (default: none).

    Returns
    -------
    list of dict per split: ``proba`` (len(test_idx), K), ``fit_time_s``, ``predict_time_s``,
    ``best_params``, ``model`` (the fitted model where ``keep``, else None).
    """
    y = np.asarray(y)
    groups = np.asarray(groups)
    for k, (tr, te) in enumerate(splits):
        if set(groups[tr].tolist()) & set(groups[te].tolist()):
            raise AssertionError(f"split {k}: runs (groups) in both train and test")
    classes = np.asarray(classes)
    col = {c: k for k, c in enumerate(classes.tolist())}
    keep = [False] * len(splits) if keep is None else list(keep)
    jobs = (delayed(_run_fold)(factory, X, y, groups, tr, te, True) if kp else
            delayed(_run_fold)(factory, X, y, groups, tr, te) for (tr, te), kp in zip(splits, keep))
    out: list[dict] = []
    for (_, te), (cls_k, p, pred, fit_s, pred_s, best, _nov, *model) in zip(
            splits, Parallel(n_jobs=n_jobs, return_as="generator")(jobs)):
        if p is None:
            raise ValueError("predict_held_out: the model has no predict_proba")
        proba = np.zeros((len(te), len(classes)))
        for j, c in enumerate(cls_k.tolist()):
            proba[:, col[c]] = p[:, j]
        out.append({"proba": proba, "fit_time_s": float(fit_s), "predict_time_s": float(pred_s),
                    "best_params": best, "model": model[0] if model else None})
        if progress is not None:
            progress(len(out), len(splits))
    return out


def assemble_result(folds, y, classes, class_names, proba: np.ndarray, fold_info: Sequence[dict],
                    table: Any = None, name: str = "") -> CVResult:
    """A :class:`CVResult` from out-of-fold probabilities computed elsewhere (same metrics).

    ``proba`` (n, K) has columns in ``classes`` order; ``fold_info`` holds per fold the entries
    added to its metrics (``fit_time_s``, ``predict_time_s``, ``n_test_groups``, ``best_params``).
    """
    classes = np.asarray(classes)
    y = np.asarray(y)
    y_pred = classes[np.argmax(np.nan_to_num(proba, nan=0.0), axis=1)].astype(y.dtype)
    return _assemble(folds, y, classes, class_names, y_pred, proba, fold_info, table, name)


def average_results(results: Sequence[CVResult], name: str = "average", table: Any = None) -> CVResult:
    """Fixed-rule ensemble: the mean of the out-of-fold probabilities of several results.

    The results must come from the same windows, folds and classes (checked) and carry
    probabilities. No weight is tuned, so nothing is learnt from the test folds. Fit and predict
    times per fold are the sums of the members'. ``table``: as in :func:`cross_validate`.
    """
    first = results[0]
    for r in results[1:]:
        if not (np.array_equal(r.y_true, first.y_true) and np.array_equal(r.fold_of, first.fold_of)
                and np.array_equal(r.classes, first.classes)):
            raise ValueError("average_results: results from different windows, folds or classes")
    if any(r.proba is None for r in results):
        raise ValueError("average_results: every result needs out-of-fold probabilities")
    proba = np.mean([r.proba for r in results], axis=0)
    y_pred = first.classes[np.argmax(proba, axis=1)]
    info = [{"fit_time_s": sum(r.fold_metrics[k]["fit_time_s"] for r in results),
             "predict_time_s": sum(r.fold_metrics[k]["predict_time_s"] for r in results),
             "n_test_groups": m["n_test_groups"], "best_params": {}}
            for k, m in enumerate(first.fold_metrics)]
    return _assemble(first.folds, first.y_true, first.classes, first.class_names, y_pred, proba, info,
                     table, name)
