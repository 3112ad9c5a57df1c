"""Boosted trees bin their features themselves: the same model as sklearn's, faster."""

import numpy as np
from sklearn.ensemble import HistGradientBoostingClassifier
from sklearn.preprocessing import FunctionTransformer

from terrainml.models.trees import BoostedTrees, to_bins, weighted_bin_thresholds


def _features(seed: int, n: int = 900) -> tuple[np.ndarray, np.ndarray]:
    """Unbalanced classes; continuous features, a feature with ties, one with few values, NaNs."""
    rng = np.random.default_rng(seed)
    y = rng.choice([0, 1, 2], size=n, p=[0.6, 0.3, 0.1])
    F = rng.normal(size=(n, 6)) + y[:, None] * np.array([0.8, 0.3, 0.0, 0.5, 0.0, 0.2])
    F[:, 2] = np.round(F[:, 2] * 3) / 3 + 0.4 * y  # ties
    F[:, 4] = rng.integers(0, 7, size=n)  # at most 255 distinct values: midpoints
    F[rng.random(n) < 0.05, 5] = np.nan
    return F, y


def test_binned_trees_give_sklearns_edges_and_probabilities():
    F, y = _features(3)
    Ftest, _ = _features(4, 300)
    ours = BoostedTrees(FunctionTransformer(), max_iter=30, learning_rate=0.2).fit_features(
        F, y, None, FunctionTransformer())
    ref = HistGradientBoostingClassifier(max_iter=30, learning_rate=0.2, min_samples_leaf=20,
                                         class_weight="balanced", random_state=0).fit(F, y)
    for mine, theirs in zip(ours.bin_thresholds_, ref._bin_mapper.bin_thresholds_):
        np.testing.assert_array_equal(mine, theirs)
    np.testing.assert_allclose(ours.predict_proba_from_features(Ftest), ref.predict_proba(Ftest), rtol=0, atol=1e-12)


def test_a_value_on_an_edge_falls_in_the_lower_bin_and_nan_stays_missing():
    edges = weighted_bin_thresholds(np.array([[0.0], [1.0], [2.0], [3.0]]), np.ones(4))
    np.testing.assert_array_equal(edges[0], [0.5, 1.5, 2.5])  # 4 distinct values: midpoints
    b = to_bins(np.array([[0.5], [0.6], [-9.0], [9.0], [np.nan]]), edges)
    np.testing.assert_array_equal(b[:4, 0], [0, 1, 0, 3])
    assert np.isnan(b[4, 0])


def test_few_windows_are_predicted_as_sklearn_predicts_them():
    F, y = _features(5)
    Ftest, _ = _features(6, 200)
    ours = BoostedTrees(FunctionTransformer(), max_iter=25, learning_rate=0.2).fit_features(
        F, y, None, FunctionTransformer())
    ref = ours.model_.predict_proba(to_bins(Ftest, ours.bin_thresholds_))  # sklearn's predictor
    few = np.concatenate([ours.predict_proba_from_features(Ftest[i:i + 1]) for i in range(len(Ftest))])
    np.testing.assert_allclose(few, ref, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ours.predict_proba_from_features(Ftest), ref, rtol=0, atol=1e-12)
    assert "_forest" not in ours.__getstate__()  # a cache, never saved with the model
