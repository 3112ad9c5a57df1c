"""Classification metrics of design §9, including what a mistake costs the controller.

* accuracy, balanced accuracy, macro-F1, confusion matrix (rows true, columns predicted, in the
  order of ``classes``), per-class recall;
* adjacent-class accuracy: share with |index(pred) - index(true)| <= 1 in the class order
  (our eight classes are ordered stiff to soft; for another dataset's class set the order is
  the dataset's, so the figure only means something when that order is physical);
* desired-slip error: |s_target(pred) - s_target(true)| from the desired-slip table
  (``DesiredSlipTable.target(class_id, state)``), per wheel state ``traction``, ``braking``,
  ``steady``; ``desired_slip_error_mean`` is the mean over windows and those three states.
  NaN when no table applies (a dataset whose classes are not the table's);
* expected calibration error (ECE): top-label confidence in ``n_bins`` equal-width bins,
  sum over bins of (bin share) * |accuracy - mean confidence|;
* inference latency per window (:func:`latency_per_window_ms`): one window per call, p50/p99.
"""

from __future__ import annotations

import time
import warnings
from typing import Any, Sequence

import numpy as np
from sklearn.metrics import (accuracy_score, balanced_accuracy_score, confusion_matrix, f1_score,
                             recall_score)

from terrainml.classes import TERRAIN_CLASSES

__all__ = ["classification_metrics", "expected_calibration_error", "desired_slip_errors",
           "latency_per_window_ms", "summarise_folds", "TARGET_STATES", "is_ordered"]

TARGET_STATES = ("traction", "braking", "steady")


def expected_calibration_error(y_true, proba: np.ndarray, classes: Sequence, n_bins: int = 10) -> float:
    """ECE of the top-label probabilities (0 = perfectly calibrated).

    Parameters
    ----------
    y_true : array (n,), labels.
    proba : ndarray (n, K), probabilities with columns in ``classes`` order.
    classes : sequence (K,), labels of the columns.
    n_bins : int, equal-width confidence bins on [0, 1].
    """
    proba = np.asarray(proba, dtype=float)
    if proba.size == 0:
        return float("nan")
    classes = np.asarray(classes)
    conf = proba.max(axis=1)
    pred = classes[proba.argmax(axis=1)]
    correct = (pred == np.asarray(y_true)).astype(float)
    bins = np.minimum((conf * n_bins).astype(int), n_bins - 1)
    ece = 0.0
    for b in range(n_bins):
        m = bins == b
        if m.any():
            ece += m.mean() * abs(correct[m].mean() - conf[m].mean())
    return float(ece)


def desired_slip_errors(y_true, y_pred, table: Any, states: Sequence[str] = TARGET_STATES) -> dict[str, np.ndarray]:
    """|s_target(pred) - s_target(true)| per window for each wheel state.

    Parameters
    ----------
    y_true, y_pred : arrays (n,), class ids of the table.
    table : object with ``target(class_id, state) -> float`` (``DesiredSlipTable``).

    Returns
    -------
    dict state -> ndarray (n,) of absolute slip differences (-).
    """
    y_true = np.asarray(y_true).astype(int)
    y_pred = np.asarray(y_pred).astype(int)
    ids = sorted(set(y_true.tolist()) | set(y_pred.tolist()))
    out = {}
    for s in states:
        lut = {c: float(table.target(int(c), s)) for c in ids}
        out[s] = np.abs(np.array([lut[p] for p in y_pred]) - np.array([lut[t] for t in y_true]))
    return out


def is_ordered(class_names: Sequence[str] | None) -> bool:
    """Whether a class set has a physical order (adjacent-class accuracy means something).

    Our eight classes are ordered stiff to soft (design §6.1), and so is any subset of them in
    id order; another dataset's class set (e.g. BorealTC's, sorted by name) is not. ``None``
    (classes known by id only) counts as ours.
    """
    if class_names is None:
        return True
    return all(str(n) in TERRAIN_CLASSES for n in class_names)


def classification_metrics(y_true, y_pred, proba: np.ndarray | None, classes: Sequence,
                           table: Any = None, ordered: bool = True) -> dict[str, Any]:
    """All per-set metrics as a JSON-friendly dict.

    Parameters
    ----------
    y_true, y_pred : arrays (n,), labels.
    proba : ndarray (n, K) or None, probabilities (columns in ``classes`` order) for the ECE.
    classes : sequence (K,), the model's classes in their physical order.
    table : desired-slip table or None.
    ordered : whether ``classes`` have a physical order (:func:`is_ordered`); False reports
        ``adjacent_accuracy`` as NaN (n/a) rather than a figure without meaning.

    Returns
    -------
    dict with ``n_windows, accuracy, balanced_accuracy, macro_f1, adjacent_accuracy, ece,
    desired_slip_error_mean``, ``desired_slip_error_<state>``, ``confusion_matrix`` (list of
    lists), ``classes``, ``recall_per_class``.
    """
    y_true = np.asarray(y_true)
    y_pred = np.asarray(y_pred)
    classes = list(np.asarray(classes).tolist())
    labels_present = sorted(set(y_true.tolist()))
    index = {c: k for k, c in enumerate(classes)}
    out: dict[str, Any] = {"n_windows": int(len(y_true))}
    if len(y_true) == 0:
        out.update({k: float("nan") for k in ("accuracy", "balanced_accuracy", "macro_f1",
                                              "adjacent_accuracy", "ece", "desired_slip_error_mean")})
        return out
    out["accuracy"] = float(accuracy_score(y_true, y_pred))
    with warnings.catch_warnings():  # a fold may hold one class, or predictions of absent ones
        warnings.simplefilter("ignore", UserWarning)
        out["balanced_accuracy"] = float(balanced_accuracy_score(y_true, y_pred))
    out["macro_f1"] = float(f1_score(y_true, y_pred, labels=labels_present, average="macro", zero_division=0))
    ti = np.array([index.get(c, -10) for c in y_true.tolist()])
    pi = np.array([index.get(c, 10 ** 6) for c in y_pred.tolist()])
    out["adjacent_accuracy"] = float(np.mean(np.abs(pi - ti) <= 1)) if ordered else float("nan")
    out["ece"] = expected_calibration_error(y_true, proba, classes) if proba is not None else float("nan")
    if table is not None:
        try:
            errs = desired_slip_errors(y_true, y_pred, table)
            for s, e in errs.items():
                out[f"desired_slip_error_{s}"] = float(e.mean())
            out["desired_slip_error_mean"] = float(np.mean([e.mean() for e in errs.values()]))
            out["desired_slip_error_max"] = float(max(e.max() for e in errs.values()))
        except (KeyError, ValueError, IndexError):
            out["desired_slip_error_mean"] = float("nan")
    else:
        out["desired_slip_error_mean"] = float("nan")
    cm = confusion_matrix(y_true, y_pred, labels=classes)
    out["confusion_matrix"] = cm.tolist()
    out["classes"] = classes
    rec = recall_score(y_true, y_pred, labels=classes, average=None, zero_division=0)
    out["recall_per_class"] = {str(c): float(r) for c, r in zip(classes, rec) if c in labels_present}
    return out


SCALARS = ("accuracy", "balanced_accuracy", "macro_f1", "adjacent_accuracy", "ece",
           "desired_slip_error_mean")


def summarise_folds(fold_metrics: Sequence[dict]) -> dict[str, dict[str, float]]:
    """Mean and std (population) over folds of each scalar metric: {name: {mean, std}}."""
    out = {}
    for k in SCALARS + tuple(f"desired_slip_error_{s}" for s in TARGET_STATES):
        vals = np.array([m.get(k, np.nan) for m in fold_metrics], dtype=float)
        if vals.size and np.isfinite(vals).any():
            out[k] = {"mean": float(np.nanmean(vals)), "std": float(np.nanstd(vals))}
    return out


def latency_per_window_ms(model: Any, X, n_calls: int = 200, warmup: int = 5) -> dict[str, float]:
    """Wall-clock ``predict_proba`` latency on one window per call.

    Parameters
    ----------
    model : fitted classifier on raw windows.
    X : Windows or ndarray (n, C, T); windows are taken cyclically.
    n_calls : int, timed calls.

    Returns
    -------
    dict ``p50_ms``, ``p99_ms``, ``mean_ms``, ``n_calls``.
    """
    n = len(X)
    if n == 0:
        return {"p50_ms": float("nan"), "p99_ms": float("nan"), "mean_ms": float("nan"), "n_calls": 0}
    one = [X.subset([k % n]) if hasattr(X, "subset") else np.asarray(X)[k % n:k % n + 1]
           for k in range(min(n, n_calls))]
    for k in range(warmup):
        model.predict_proba(one[k % len(one)])
    times = np.empty(n_calls)
    for k in range(n_calls):
        x = one[k % len(one)]
        t0 = time.perf_counter()
        model.predict_proba(x)
        times[k] = (time.perf_counter() - t0) * 1e3
    return {"p50_ms": float(np.percentile(times, 50)), "p99_ms": float(np.percentile(times, 99)),
            "mean_ms": float(times.mean()), "n_calls": int(n_calls)}
