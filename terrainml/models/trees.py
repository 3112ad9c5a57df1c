"""Gradient-boosted trees on window features (design §9): a second, non-kernel classifier.

:class:`BoostedTrees` is ``sklearn.ensemble.HistGradientBoostingClassifier`` on
:class:`~terrainml.features.side_channel.SideChannelFeatures`. Trees need no feature scaling
and cope with features of any spread, which the RBF kernel of the SVM does not.
"""

from __future__ import annotations

import numpy as np
from sklearn.base import BaseEstimator, ClassifierMixin, clone
from sklearn.ensemble import HistGradientBoostingClassifier
from sklearn.utils.validation import check_is_fitted

from terrainml.features.side_channel import SideChannelFeatures

__all__ = ["BoostedTrees"]


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
    classes_ : ndarray (K,). features_ : the fitted transformer. model_ : the fitted trees.
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
        self.model_ = HistGradientBoostingClassifier(
            max_iter=int(self.max_iter), learning_rate=float(self.learning_rate),
            # sklearn's 20 samples per leaf, but at most a quarter of the data: with fewer
            # than 40 windows the default leaves no split at all and predicts one class
            min_samples_leaf=max(1, min(20, len(F) // 4)),
            class_weight="balanced", random_state=self.random_state)
        self.model_.fit(F, np.asarray(y))
        self.classes_ = self.model_.classes_
        return self

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
        return self.model_.predict_proba(F)

    def predict(self, X) -> np.ndarray:
        return self.classes_[np.argmax(self.predict_proba(X), axis=1)]
