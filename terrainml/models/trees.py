"""Gradient-boosted trees on window features (design §9): a second, non-kernel classifier.

:class:`BoostedTrees` is ``sklearn.ensemble.HistGradientBoostingClassifier`` on
:class:`~terrainml.features.side_channel.SideChannelFeatures`. Trees need no feature scaling
and cope with features of any spread, which the RBF kernel of the SVM does not.

The features are binned here, before the trees see them (:func:`weighted_bin_thresholds`,
:func:`to_bins`), into the same bins sklearn's own binning would choose. Why by hand: with
``class_weight`` sklearn (1.8+) finds each of a feature's 254 bin edges by its own call of a
weighted percentile, and on BorealTC's 280 side-channel features x 4,500 windows that took 47 of
the 53 s of a 40-tree fit (cProfile). Computing every edge of a feature in one pass gives the
same edges, so the trees, probabilities and choice are those of the plain sklearn model (test:
``test_binned_trees_give_sklearns_edges_and_probabilities``), at a fraction of the time (BENCHMARKS "Time
to an answer").
"""

from __future__ import annotations

import numpy as np
from sklearn.base import BaseEstimator, ClassifierMixin, clone
from sklearn.ensemble import HistGradientBoostingClassifier
from sklearn.utils.class_weight import compute_sample_weight
from sklearn.utils.validation import check_is_fitted

from terrainml.features.side_channel import SideChannelFeatures

__all__ = ["BoostedTrees", "weighted_bin_thresholds", "to_bins", "MAX_BINS", "FEW_WINDOWS"]

#: at most this many windows are predicted by :class:`_Forest` (one array pass over every tree);
#: more by sklearn's own predictor (per tree, multithreaded: faster on a batch)
FEW_WINDOWS = 64

#: bins per feature besides the missing-value bin: sklearn's default ``max_bins``
MAX_BINS = 255
#: sklearn's cap of a bin edge (``_hist_gradient_boosting.common.ALMOST_INF``)
_ALMOST_INF = 1e300


def _edges_of(col: np.ndarray, w: np.ndarray, max_bins: int) -> np.ndarray:
    """Bin edges of one feature as sklearn's ``_find_binning_thresholds`` finds them: the
    midpoints of its distinct values when it has at most ``max_bins``, else the weighted
    percentiles 100 k / max_bins (k = 1 .. max_bins - 1) by the "averaged inverted CDF" rule,
    all in one pass over the sorted values."""
    keep = ~np.isnan(col) & (w != 0)
    col, w = col[keep], w[keep]
    order = np.argsort(col, kind="stable")
    col, w = col[order], w[order]
    distinct = np.unique(col)
    if len(distinct) <= 1:
        return np.asarray([], dtype=float)
    if len(distinct) <= max_bins:
        edges = (distinct[:-1] + distinct[1:]) / 2
    else:
        cdf = np.cumsum(w)
        rank = np.linspace(0, 100, num=max_bins + 1)[1:-1] / 100 * cdf[-1]
        idx = np.clip(np.searchsorted(cdf, rank), 0, len(col) - 1)  # cdf[idx-1] < rank <= cdf[idx]
        above = (cdf[idx] - rank) > np.finfo(float).eps
        nxt = np.clip(idx + 1, 0, len(col) - 1)
        edges = np.where(above, col[idx], (col[idx] + col[nxt]) / 2)
    return np.clip(np.unique(edges), None, _ALMOST_INF)


def weighted_bin_thresholds(F: np.ndarray, sample_weight: np.ndarray, max_bins: int = MAX_BINS) -> list:
    """Per feature, the increasing bin edges (at most ``max_bins - 1``) of ``F`` (n, n_features)
    under ``sample_weight`` (n,): the edges sklearn's histogram gradient boosting bins by."""
    F = np.asarray(F, dtype=float)
    w = np.asarray(sample_weight, dtype=float)
    return [_edges_of(F[:, j], w, max_bins) for j in range(F.shape[1])]


def to_bins(F: np.ndarray, thresholds: list) -> np.ndarray:
    """Bin index (as float) of every value of ``F`` (n, n_features): the number of the feature's
    edges below the value, so ``x <= edge k`` exactly when its bin is ``<= k``; NaN stays NaN (the
    trees' missing-value rule)."""
    F = np.asarray(F, dtype=float)
    out = np.empty_like(F)
    for j, edges in enumerate(thresholds):
        out[:, j] = np.searchsorted(edges, F[:, j], side="left")
    out[np.isnan(F)] = np.nan
    return out


class _Forest:
    """Every tree of a fitted ``HistGradientBoostingClassifier`` as flat arrays, walked for all trees
    at once: the raw predictions of a few windows in one numpy pass per tree level.

    Why by hand: sklearn predicts tree by tree from Python, 1,500 calls for 300 iterations x 5
    classes, 18 ms for one window (BorealTC, measured); serving classifies one window at a time.
    The walk is sklearn's rule (``_predictor.pyx``: NaN goes to the node's missing side, else
    ``x <= num_threshold`` goes left), summed in iteration order; tested equal to sklearn's
    probabilities (``test_few_windows_are_predicted_as_sklearn_predicts_them``).
    """

    def __init__(self, model: HistGradientBoostingClassifier):
        trees = [p for it in model._predictors for p in it]
        if any(t.nodes["is_categorical"].any() for t in trees):
            raise ValueError("_Forest: categorical splits are not supported")
        sizes = np.array([len(t.nodes) for t in trees])
        offset = np.concatenate([[0], np.cumsum(sizes)[:-1]])
        nodes = np.concatenate([t.nodes for t in trees])
        shift = np.repeat(offset, sizes)
        self.roots = offset
        self.feature = nodes["feature_idx"].astype(np.int64)
        self.threshold = nodes["num_threshold"].astype(float)
        self.nan_left = nodes["missing_go_to_left"].astype(bool)
        self.left = nodes["left"].astype(np.int64) + shift
        self.right = nodes["right"].astype(np.int64) + shift
        self.is_leaf = nodes["is_leaf"].astype(bool)
        self.value = nodes["value"].astype(float)
        self.depth = int(nodes["depth"].max())
        self.n_per_iteration = int(model.n_trees_per_iteration_)
        self.baseline = np.asarray(model._baseline_prediction, dtype=float).reshape(-1)

    def raw(self, F: np.ndarray) -> np.ndarray:
        """Raw predictions (n, trees per iteration) of features F (n, n_features)."""
        node = np.broadcast_to(self.roots, (len(F), len(self.roots))).copy()
        rows = np.arange(len(F))[:, None]
        for _ in range(self.depth):
            x = F[rows, self.feature[node]]
            go_left = np.where(np.isnan(x), self.nan_left[node], x <= self.threshold[node])
            node = np.where(self.is_leaf[node], node, np.where(go_left, self.left[node], self.right[node]))
        leaves = self.value[node].reshape(len(F), -1, self.n_per_iteration)  # (n, iterations, K)
        raw = np.broadcast_to(self.baseline, (len(F), self.n_per_iteration)).copy()
        for i in range(leaves.shape[1]):  # sklearn's order of summation
            raw += leaves[:, i, :]
        return raw


class BoostedTrees(ClassifierMixin, BaseEstimator):
    """Gradient-boosted trees on raw windows through a stateless feature transformer.

    Fixed settings (no search: ``max_iter`` trees of learning rate ``learning_rate``, balanced
    class weights, otherwise sklearn's defaults; chosen before evaluation, not tuned on any
    fold). Deterministic under ``random_state``.

    Parameters
    ----------
    features : stateless transformer of windows (n, C, T) to features (n, F); default
        ``SideChannelFeatures()``.
    max_iter : int >= 1, boosting iterations (trees per class).
    learning_rate : float > 0.
    random_state : int.

    Attributes
    ----------
    classes_ : ndarray (K,). features_ : the fitted transformer. model_ : the fitted trees (on
    bin indices). bin_thresholds_ : list of n_features increasing arrays, the bin edges of each
    feature (in the feature's units).
    """

    def __init__(self, features: SideChannelFeatures | None = None, max_iter: int = 300,
                 learning_rate: float = 0.05, random_state: int = 0):
        self.features = features
        self.max_iter = max_iter
        self.learning_rate = learning_rate
        self.random_state = random_state

    def fit(self, X, y, groups=None):
        """Fit on windows ``X`` (Windows or (n, C, T)) and labels ``y`` (n,).

        ``groups`` is accepted (and unused: no inner search) so that cross-validation can call
        every model alike.
        """
        features = clone(self.features) if self.features is not None else SideChannelFeatures()
        return self.fit_features(features.fit(X).transform(X), y, groups, features)

    def fit_features(self, F: np.ndarray, y, groups=None, features=None) -> "BoostedTrees":
        """Fit on the feature matrix ``F`` (n, n_features) of n windows, computed elsewhere.

        The same model as :meth:`fit` on the windows: ``features`` is the fitted, stateless
        transformer whose ``transform`` of those windows gives ``F`` (it becomes ``features_``,
        so the fitted model predicts on raw windows).
        """
        if int(self.max_iter) < 1 or not float(self.learning_rate) > 0:
            raise ValueError("BoostedTrees: max_iter must be >= 1 and learning_rate > 0")
        if features is None:
            raise ValueError("BoostedTrees.fit_features: give the fitted feature transformer of F")
        self.features_ = features
        F = np.asarray(F, dtype=float)
        y = np.asarray(y)
        # the edges sklearn would find from the balanced class weights (module docstring); the
        # trees then see at most MAX_BINS distinct values per feature and bin them as they are
        self.bin_thresholds_ = weighted_bin_thresholds(F, compute_sample_weight("balanced", y))
        self.model_ = HistGradientBoostingClassifier(
            max_iter=int(self.max_iter), learning_rate=float(self.learning_rate),
            # sklearn's 20 samples per leaf, but at most a quarter of the data: with fewer
            # than 40 windows the default leaves no split at all and predicts one class
            min_samples_leaf=max(1, min(20, len(F) // 4)),
            class_weight="balanced", random_state=self.random_state)
        self.model_.fit(to_bins(F, self.bin_thresholds_), y)
        self.classes_ = self.model_.classes_
        return self

    def __getstate__(self):
        state = super().__getstate__()
        state.pop("_forest", None)  # rebuilt from model_ after loading; never persisted
        return state

    def predict_proba(self, X) -> np.ndarray:
        """Class probabilities (n, K), columns in ``classes_`` order."""
        return self.predict_proba_and_features(X)[0]

    def predict_proba_and_features(self, X) -> tuple[np.ndarray, np.ndarray]:
        """Probabilities (n, K) of windows X and the features (n, F) they came from (computed
        once: serving hands them on to the novelty score)."""
        check_is_fitted(self, "model_")
        F = self.features_.transform(X)
        return self.predict_proba_from_features(F), F

    def predict_proba_from_features(self, F: np.ndarray) -> np.ndarray:
        """Class probabilities (n, K) of the feature matrix F (n, F) of n windows (the output of
        ``features_.transform``)."""
        check_is_fitted(self, "model_")
        thresholds = getattr(self, "bin_thresholds_", None)  # None: a model saved before binning here
        F = np.asarray(F, dtype=float)
        F = F if thresholds is None else to_bins(F, thresholds)
        if len(F) > FEW_WINDOWS:
            return self.model_.predict_proba(F)
        forest = self.__dict__.get("_forest")
        if forest is None or forest[0] is not self.model_:  # built once per fitted (or loaded) model
            forest = (self.model_, _Forest(self.model_))
            self.__dict__["_forest"] = forest
        return self.model_._loss.predict_proba(forest[1].raw(F))

    def predict(self, X) -> np.ndarray:
        return self.classes_[np.argmax(self.predict_proba(X), axis=1)]
