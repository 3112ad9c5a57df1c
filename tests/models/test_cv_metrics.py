"""Grouped CV and metrics against independent truth (design §9)."""

from __future__ import annotations

import numpy as np
import pytest

from terrainml.evaluation.folds import check_groups_not_split, grouped_folds
from terrainml.evaluation.metrics import (classification_metrics, desired_slip_errors,
                                          expected_calibration_error)


def _labels(n_runs_per_class=6, classes=(0, 1, 2, 3), windows_per_run=(3, 9)):
    rng = np.random.default_rng(0)
    y, g = [], []
    for c in classes:
        for r in range(n_runs_per_class):
            k = int(rng.integers(*windows_per_run))
            y += [c] * k
            g += [f"c{c}r{r}"] * k
    return np.array(y), np.array(g)


def test_no_run_in_two_folds_and_every_run_tested_once():
    y, g = _labels()
    folds = grouped_folds(y, g, 5, seed=3)
    assert len(folds) == 5
    tested = [set(g[te]) for _, te in folds]
    for k, (tr, te) in enumerate(folds):
        assert not set(g[tr]) & set(g[te])
        for j in range(k):
            assert not tested[j] & tested[k]
    assert set().union(*tested) == set(g)
    assert sorted(np.concatenate([te for _, te in folds]).tolist()) == list(range(len(y)))
    check_groups_not_split(folds, g)


def test_same_seed_same_folds_other_seed_other_folds():
    y, g = _labels()
    a = grouped_folds(y, g, 5, seed=11)
    b = grouped_folds(y, g, 5, seed=11)
    c = grouped_folds(y, g, 5, seed=12)
    assert all(np.array_equal(x[1], z[1]) for x, z in zip(a, b))
    assert not all(np.array_equal(x[1], z[1]) for x, z in zip(a, c))


def test_shared_run_is_detected():
    g = np.array(["a", "a", "b", "b"])
    with pytest.raises(AssertionError, match="run"):
        check_groups_not_split([(np.array([0, 2]), np.array([1, 3]))], g)


def test_ece_hand_worked():
    # two windows at confidence 0.9 (one right), two at 0.6 (both right)
    proba = np.array([[0.9, 0.1], [0.9, 0.1], [0.4, 0.6], [0.4, 0.6]])
    y = np.array([0, 1, 1, 1])
    # bins: 0.9 -> acc 0.5, |0.5-0.9| = 0.4, share 0.5; 0.6 -> acc 1, |1-0.6| = 0.4, share 0.5
    assert expected_calibration_error(y, proba, [0, 1]) == pytest.approx(0.4)


class _Table:
    T = {0: (0.16, -0.16, 0.0), 2: (0.23, -0.17, 0.12), 6: (0.42, -0.55, 0.30)}

    def target(self, cid, state):
        return self.T[cid][("traction", "braking", "steady").index(state)]


def test_desired_slip_error_and_adjacent_accuracy_hand_worked():
    y_true = np.array([0, 0, 2, 6])
    y_pred = np.array([0, 2, 2, 2])
    e = desired_slip_errors(y_true, y_pred, _Table())
    np.testing.assert_allclose(e["traction"], [0, 0.07, 0, 0.19])
    np.testing.assert_allclose(e["braking"], [0, 0.01, 0, 0.38])
    m = classification_metrics(y_true, y_pred, None, [0, 2, 6], _Table())
    assert m["accuracy"] == 0.5
    assert m["balanced_accuracy"] == pytest.approx((0.5 + 1 + 0) / 3)
    # class order (0, 2, 6): 0->2 and 6->2 are adjacent in that order
    assert m["adjacent_accuracy"] == 1.0
    expected = np.mean([np.mean([0, 0.07, 0, 0.19]), np.mean([0, 0.01, 0, 0.38]), np.mean([0, 0.12, 0, 0.18])])
    assert m["desired_slip_error_mean"] == pytest.approx(expected)
    assert m["confusion_matrix"] == [[1, 1, 0], [0, 1, 0], [0, 1, 0]]
