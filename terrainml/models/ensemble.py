"""Fixed probability averages of fitted classifiers (design §9): ``svm+hgb``, ``svm+cnn``, ...

:class:`ProbabilityAverage` is the mean of its members' ``predict_proba`` (a fixed rule, nothing
tuned: the same rule as :func:`terrainml.evaluation.cv.average_results` applies to out-of-fold
probabilities). It holds no parameters of its own: a model folder stores its members as the
other models (skops, safetensors) and names them in the manifest entry of the average
(:mod:`terrainml.models.artifacts`), which rebuilds it with :meth:`ProbabilityAverage.from_fitted`.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np
from sklearn.base import BaseEstimator, ClassifierMixin, clone
from sklearn.utils.validation import check_is_fitted

__all__ = ["ProbabilityAverage"]


class ProbabilityAverage(ClassifierMixin, BaseEstimator):
    """Mean of the class probabilities of several classifiers on the same windows.

    Parameters
    ----------
    members : sequence of unfitted classifiers with ``fit(X, y, groups=)`` and ``predict_proba``.

    Attributes
    ----------
    members_ : list of fitted classifiers. classes_ : ndarray (K,), the members' common classes.
    """

    def __init__(self, members: Sequence[Any] = ()):
        self.members = members

    def fit(self, X, y, groups=None):
        """Fit a clone of every member on windows ``X`` and labels ``y`` (n,), grouped by ``groups``."""
        if len(self.members) < 2:
            raise ValueError("ProbabilityAverage: needs at least 2 members")
        fitted = []
        for m in self.members:
            c = clone(m)
            c.fit(X, y, groups=groups)
            fitted.append(c)
        return self._set_fitted(fitted)

    @classmethod
    def from_fitted(cls, members: Sequence[Any]) -> "ProbabilityAverage":
        """An average over already fitted members (their classes must agree, order included)."""
        return cls(list(members))._set_fitted(list(members))

    def _set_fitted(self, fitted: list) -> "ProbabilityAverage":
        if len(fitted) < 2:
            raise ValueError("ProbabilityAverage: needs at least 2 members")
        classes = np.asarray(fitted[0].classes_)
        for m in fitted[1:]:
            if not np.array_equal(np.asarray(m.classes_), classes):
                raise ValueError(f"ProbabilityAverage: members' classes differ ({classes.tolist()} vs "
                                 f"{np.asarray(m.classes_).tolist()})")
        self.members_ = fitted
        self.classes_ = classes
        return self

    def predict_proba(self, X) -> np.ndarray:
        """Mean of the members' probabilities, shape (n, K), columns in ``classes_`` order."""
        check_is_fitted(self, "members_")
        return self.mean_proba([m.predict_proba(X) for m in self.members_])

    @staticmethod
    def mean_proba(probas: Sequence[np.ndarray]) -> np.ndarray:
        """The average of the members' probabilities: ``probas`` one (n, K) array per member, in
        ``members_`` order; returns (n, K)."""
        return np.mean([np.asarray(p, dtype=float) for p in probas], axis=0)

    def predict(self, X) -> np.ndarray:
        return self.classes_[np.argmax(self.predict_proba(X), axis=1)]
