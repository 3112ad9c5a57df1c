"""Fold strategies for cross-validation (design §9): which windows are tested together.

Every strategy returns a list of ``(train_idx, test_idx)`` window index arrays that never split
a *group*, checked by :func:`check_groups_not_split`:

* :func:`grouped_folds`: ``StratifiedGroupKFold(n_splits, shuffle=True, random_state=seed)``
  with the run id as group, so no run is in both training and test: the figure a new run on a
  known terrain can expect (the default of :func:`terrainml.evaluation.cv.cross_validate`);
* :func:`chunk_folds`: ``StratifiedKFold(n_splits, shuffle=True, random_state=seed)`` over
  chunks (e.g. the BorealTC authors' 5-s pieces of a run, LaRocque et al., IROS 2024), stratified
  on the chunks' labels and *not* grouped by run: every window follows its chunk, but chunks of
  one run fall into training and test, so neighbouring pieces of one drive are in both.

* :func:`run_partition`: the runs themselves split into disjoint groups (stratified by the
  run's class, weighted by its length), independent of any window spec, so that the candidates
  of the nested selection (:mod:`terrainml.pipeline.select`), whose window specs keep different
  windows of the same runs, are tested on the same runs; :func:`folds_of_partition` gives the
  window folds of one spec.

The same seed gives the same folds.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from sklearn.model_selection import StratifiedGroupKFold, StratifiedKFold

__all__ = ["grouped_folds", "chunk_folds", "check_groups_not_split", "run_partition", "folds_of_partition"]


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


def chunk_folds(y, chunks, n_splits: int = 5, seed: int = 0) -> list[tuple[np.ndarray, np.ndarray]]:
    """Stratified K-fold over chunks (not grouped by run), seeded; a chunk is never split.

    Parameters
    ----------
    y : array (n,), labels; every window of a chunk has its chunk's label.
    chunks : array (n,), chunk ids of the windows.
    n_splits : int >= 2. seed : int (the BorealTC authors' ``RANDOM_STATE`` is 21).

    Returns
    -------
    list of (train_idx, test_idx) window index arrays.
    """
    y = np.asarray(y)
    chunks = np.asarray(chunks)
    ids, first = np.unique(chunks, return_index=True)  # chunk ids in ascending order
    cv = StratifiedKFold(n_splits=int(n_splits), shuffle=True, random_state=int(seed))
    folds = []
    for _, te_chunks in cv.split(np.zeros(len(ids)), y[first]):
        te = np.isin(chunks, ids[te_chunks])
        folds.append((np.flatnonzero(~te), np.flatnonzero(te)))
    return folds


def run_partition(run_ids, run_classes, n_splits: int = 5, seed: int = 0,
                  weights=None) -> list[np.ndarray]:
    """The runs split into ``n_splits`` disjoint groups, stratified by class, seeded.

    ``StratifiedGroupKFold(n_splits, shuffle=True, random_state=seed)`` over ``weights[i]``
    copies of run ``i`` (e.g. its length in seconds; default 1 each), so the groups hold about
    the same share of every class's driving time.

    Parameters
    ----------
    run_ids : array (R,), distinct run ids. run_classes : array (R,), each run's class.
    n_splits : int >= 2 (lowered to the runs of the class with the fewest, floor 2).
    seed : int. weights : array (R,) of positive ints, or None.

    Returns
    -------
    list of ``n_splits`` arrays of run ids (every run in exactly one).
    """
    ids = np.asarray(run_ids)
    cls = np.asarray(run_classes)
    if len(set(ids.tolist())) != len(ids):
        raise ValueError("run_partition: run ids must be distinct")
    w = np.ones(len(ids), dtype=np.int64) if weights is None else np.maximum(1, np.asarray(weights, dtype=np.int64))
    per_class = min(int((cls == c).sum()) for c in np.unique(cls))
    k = int(max(2, min(n_splits, per_class)))
    if len(ids) < k:
        raise ValueError(f"run_partition needs at least {k} runs, got {len(ids)}")
    rep = np.repeat(np.arange(len(ids)), w)
    cv = StratifiedGroupKFold(n_splits=k, shuffle=True, random_state=int(seed))
    return [ids[np.unique(rep[te])] for _, te in cv.split(np.zeros(len(rep)), cls[rep], rep)]


def folds_of_partition(groups, partition, held: list[int] | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
    """Window folds (train_idx, test_idx) of a run partition: fold ``d`` tests the windows of
    partition group ``d`` and trains on the windows of the other groups in ``held`` (default all).

    ``groups`` (n,) are the windows' run ids; windows of runs in no listed group are in neither part.
    """
    groups = np.asarray(groups)
    held = list(range(len(partition))) if held is None else list(held)
    member = {g: np.isin(groups, partition[g]) for g in held}
    return [(np.flatnonzero(np.any([member[o] for o in held if o != d], axis=0)), np.flatnonzero(member[d]))
            for d in held]


def check_groups_not_split(folds, groups) -> None:
    """Raise AssertionError when a group (a run, a chunk) is in the training and test parts of a
    fold, or in the test parts of two folds."""
    groups = np.asarray(groups)
    seen: dict[Any, int] = {}
    for k, (tr, te) in enumerate(folds):
        test_groups = set(groups[te].tolist())
        if test_groups & set(groups[tr].tolist()):
            raise AssertionError(f"fold {k}: runs (groups) in both train and test")
        for r in test_groups:
            if r in seen:
                raise AssertionError(f"run (group) {r!r} in the test parts of folds {seen[r]} and {k}")
            seen[r] = k
