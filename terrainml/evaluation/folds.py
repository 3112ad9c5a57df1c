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

The same seed gives the same folds.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from sklearn.model_selection import StratifiedGroupKFold, StratifiedKFold

__all__ = ["grouped_folds", "chunk_folds", "check_groups_not_split"]


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
