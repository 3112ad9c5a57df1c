"""RBF SVM on window features (design §9), a scikit-learn classifier on raw windows.

:class:`SVMClassifier` takes the same input as the CNN (raw windows (n, C, T): a
:class:`~terrainml.features.windows.Windows` or an array with ``channel_names``), computes the
:class:`~terrainml.features.sets.FeatureSet` internally and fits::

    [feature selection] -> Pipeline(StandardScaler, SVC(kernel="rbf", class_weight="balanced"))

* feature selection (``select_features=True``, beyond design §9, the signal and feature
  selection the classifier's authors studied): an ``ExtraTreesClassifier`` (seeded,
  class-balanced) is fitted once on the training windows and ``SelectFromModel`` keeps the
  features whose impurity importance is above the mean. An RBF kernel weighs every
  standardised feature equally, so the ~300 features of the ``all`` set, many of which
  describe the manoeuvre rather than the ground, drown the few that separate close classes
  (gravel vs short grass, pavement vs compacted dirt). Measured on the simulated dataset
  (grouped 5-fold CV by run): balanced accuracy 0.93 without, 0.98 with. Only the boolean mask
  is kept (``feature_mask_``), not the forest. The selector sees the outer training data only;
  the inner search then runs on the selected features (its inner score is slightly
  optimistic; the outer CV is not affected);
* C and gamma by an inner grid search grouped by run (``StratifiedGroupKFold`` over the
  ``groups`` given to ``fit``, seeded; no run in both parts of an inner split), scored by
  balanced accuracy. It is sklearn's ``GridSearchCV`` computed on precomputed kernel matrices
  (:func:`_kernel_search`: one RBF kernel per split and gamma shared by every C; the same
  scores, about half the CPU time of sklearn's search on BorealTC's chunks windows), or
  ``GridSearchCV`` itself above :data:`KERNEL_SEARCH_MAX_WINDOWS` training windows per split;
* calibrated probabilities: ``CalibratedClassifierCV`` (sigmoid, ``ensemble=False``) whose
  calibration data are the out-of-fold decision values of the same grouped inner splits;
  ``predict`` is the argmax of the calibrated probabilities, so the policy and the labels agree.

Fewer runs per class than ``inner_folds`` lower the number of inner folds (down to 2); a single
run falls back to window-level stratified folds (documented: windows of one run then leak).

Inference (``predict_proba``/``predict``) runs a numpy transcription of the fitted calibrated
pipeline (:class:`_CompiledSVM`, derived from ``model_`` on first use and never stored): only the
selected features are computed, then ``(F - mean) / scale``, the RBF kernel against the support
vectors, libsvm's one-vs-one sums from ``dual_coef_``/``intercept_``, sklearn's one-vs-rest
aggregation and the per-class sigmoids. It gives sklearn's numbers (tests check the decision
values and probabilities against sklearn itself) at a fraction of the per-call cost, which
matters when the stream classifies one window at a time. A model of another shape (not
StandardScaler + RBF SVC + sigmoid calibration), or non-finite features, go through sklearn.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy.special import expit
from sklearn.base import BaseEstimator, ClassifierMixin, clone
from sklearn.calibration import CalibratedClassifierCV
from sklearn.exceptions import NotFittedError
from sklearn.metrics import balanced_accuracy_score
from sklearn.ensemble import ExtraTreesClassifier
from sklearn.model_selection import GridSearchCV, StratifiedGroupKFold, StratifiedKFold
from sklearn.pipeline import Pipeline
from sklearn.preprocessing import StandardScaler
from sklearn.svm import SVC
from sklearn.utils.validation import check_is_fitted

from terrainml.features.sets import FeatureSet

__all__ = ["SVMClassifier", "inner_splits"]

DEFAULT_C = (1.0, 10.0, 100.0, 1000.0, 10000.0)
DEFAULT_GAMMA = ("scale", 0.0001, 0.0003, 0.001, 0.003, 0.01)
KERNEL_CHUNK_ELEMENTS = 1 << 20  # windows x support vectors per kernel block (bounds memory)
#: the C/gamma search runs on precomputed kernel matrices up to this many training windows per
#: inner split (at most four n x n float64 matrices at once: 4 x 8 x 4000^2 B = 0.5 GB); above,
#: sklearn's search
KERNEL_SEARCH_MAX_WINDOWS = 4000

_add = np.add.reduce


def inner_splits(y: np.ndarray, groups: np.ndarray | None, n_splits: int, seed: int) -> list:
    """Grouped, stratified, seeded splits (train_idx, test_idx) for inner search/calibration."""
    y = np.asarray(y)
    n = len(y)
    if groups is None:
        groups = np.arange(n)
    groups = np.asarray(groups)
    # runs per class limit the folds
    per_class = [len(np.unique(groups[y == c])) for c in np.unique(y)]
    k = int(max(2, min(n_splits, min(per_class))))
    if len(np.unique(groups)) >= k and min(per_class) >= 2:
        cv = StratifiedGroupKFold(n_splits=k, shuffle=True, random_state=seed)
        return list(cv.split(np.zeros(n), y, groups))
    counts = np.bincount(np.unique(y, return_inverse=True)[1])
    k = int(max(2, min(k, counts.min())))
    return list(StratifiedKFold(n_splits=k, shuffle=True, random_state=seed).split(np.zeros(n), y))


def _kernel_search(F: np.ndarray, y: np.ndarray, splits: list, Cs: list, gammas: list) -> tuple[dict, float]:
    """``GridSearchCV(Pipeline(StandardScaler, SVC(rbf, balanced)), {C, gamma}, balanced accuracy)``
    over ``splits``, computed on precomputed kernel matrices: ({"C", "gamma"} of the best mean
    inner score, that score).

    The same search (tests check the scores against sklearn's): per split the scaler is fitted
    on the training part, and per gamma the RBF kernel matrices of the training part and of the
    held-out part against it are computed once and shared by every C (sklearn evaluates the
    kernel anew inside libsvm for every C, for the fit and again for the scoring, which is most
    of an SVM fit's time). ``"scale"`` is sklearn's 1 / (n_features x variance) of the scaled
    training part. Ties go to the first parameters in sklearn's order (C, then gamma).
    """
    scores = np.zeros((len(Cs), len(gammas), len(splits)))
    for s, (tr, te) in enumerate(splits):
        scaler = StandardScaler().fit(F[tr])
        Ztr, Zte = scaler.transform(F[tr]), scaler.transform(F[te])
        sq_tr, sq_te = _add(Ztr * Ztr, axis=1), _add(Zte * Zte, axis=1)
        # squared distances, clipped at 0 (rounding), as sklearn's rbf_kernel computes them
        D_tr = np.maximum(sq_tr[:, None] - 2.0 * (Ztr @ Ztr.T) + sq_tr[None, :], 0.0)
        np.fill_diagonal(D_tr, 0.0)
        D_te = np.maximum(sq_te[:, None] - 2.0 * (Zte @ Ztr.T) + sq_tr[None, :], 0.0)
        for j, g in enumerate(gammas):
            gamma = 1.0 / (Ztr.shape[1] * Ztr.var()) if g == "scale" else float(g)
            K_tr, K_te = np.exp(-gamma * D_tr), np.exp(-gamma * D_te)
            for i, C in enumerate(Cs):
                svc = SVC(kernel="precomputed", C=C, class_weight="balanced").fit(K_tr, y[tr])
                with warnings.catch_warnings():  # an inner fold may miss a class
                    warnings.simplefilter("ignore", UserWarning)
                    scores[i, j, s] = balanced_accuracy_score(y[te], svc.predict(K_te))
    mean = scores.mean(axis=2)
    i, j = np.unravel_index(int(np.argmax(mean)), mean.shape)  # first maximum in (C, gamma) order
    return {"C": Cs[i], "gamma": gammas[j]}, float(mean[i, j])


@dataclass(frozen=True, eq=False)
class _CompiledSVM:
    """The fitted calibrated pipeline of an :class:`SVMClassifier` as plain arrays.

    Derived from ``model_`` (never stored: artifacts keep sklearn's objects). With d selected
    features, V support vectors, K classes and P = K (K - 1) / 2 class pairs:

    * ``mean``/``scale`` (d,) or None: the StandardScaler, z = (F - mean) / scale;
    * ``sv_t_m2`` (d, V) = -2 SV^T, ``sv_sq`` (V,) the squared norms of the support vectors,
      ``gamma``: K(z, s) = exp(-gamma |z - s|^2);
    * ``coef`` (V, P), ``intercept`` (P,): libsvm's one-vs-one values ovo = K(z, SV) coef +
      intercept (pair (i, j): class i's vectors weighted by ``dual_coef_[j - 1]``, class j's
      by ``dual_coef_[i]``);
    * ``conf`` (P, K), ``vote_diff`` (P, K), ``vote_base`` (K,): sklearn's one-vs-rest
      aggregation (``_ovr_decision_function``) as matrices;
    * ``neg_a``/``neg_b`` (K,) or (1,): the sigmoid calibrators negated, p_k = expit(-(a_k d_k + b_k)).
    """

    columns: np.ndarray | None  # selected columns of a FeatureSet's output, None: not a FeatureSet
    n_features: int
    n_classes: int
    mean: np.ndarray | None
    scale: np.ndarray | None
    sv_t_m2: np.ndarray
    sv_sq: np.ndarray
    gamma: float
    coef: np.ndarray
    intercept: np.ndarray
    conf: np.ndarray
    vote_diff: np.ndarray
    vote_base: np.ndarray
    neg_a: np.ndarray
    neg_b: np.ndarray


def _compile_svm(model, mask: np.ndarray | None, features) -> _CompiledSVM | None:
    """Arrays of a fitted ``CalibratedClassifierCV(Pipeline(StandardScaler, SVC(rbf)), sigmoid,
    ensemble=False)``; None when the model has any other shape (then sklearn predicts)."""
    if not isinstance(model, CalibratedClassifierCV):
        return None
    ccs = getattr(model, "calibrated_classifiers_", ())
    if len(ccs) != 1 or getattr(ccs[0], "method", None) != "sigmoid":
        return None
    cc = ccs[0]
    pipe = cc.estimator
    if not isinstance(pipe, Pipeline) or len(pipe.steps) != 2:
        return None
    scaler, svc = pipe.steps[0][1], pipe.steps[1][1]
    if type(scaler) is not StandardScaler or type(svc) is not SVC:
        return None
    if svc.kernel != "rbf" or getattr(svc, "_sparse", True) or getattr(svc, "_impl", None) != "c_svc" \
            or svc.decision_function_shape != "ovr":
        return None
    classes = np.asarray(svc.classes_)
    K = len(classes)
    if K < 2 or not np.array_equal(np.asarray(cc.classes), classes):
        return None  # calibrated columns must be the SVC's classes, in order
    cals = list(cc.calibrators)
    if len(cals) != (1 if K == 2 else K) or not all(
            type(c).__name__ == "_SigmoidCalibration" and np.ndim(c.a_) == 0 and np.ndim(c.b_) == 0
            for c in cals):
        return None
    sv = np.ascontiguousarray(svc.support_vectors_, dtype=np.float64)
    dual = np.asarray(svc._dual_coef_, dtype=np.float64)
    n_sv = np.asarray(svc._n_support, dtype=np.intp)
    d = sv.shape[1]
    if sv.ndim != 2 or dual.shape != (K - 1, len(sv)) or n_sv.sum() != len(sv) or len(n_sv) != K:
        return None
    if getattr(scaler, "n_features_in_", d) != d or (mask is not None and int(np.sum(mask)) != d):
        raise ValueError(f"SVMClassifier: inconsistent fitted model: the scaler sees "
                         f"{getattr(scaler, 'n_features_in_', '?')} features, the SVC {d}, the "
                         f"feature selection keeps {None if mask is None else int(np.sum(mask))}")
    mean = np.asarray(scaler.mean_, dtype=np.float64) if scaler.with_mean else None
    scale = np.asarray(scaler.scale_, dtype=np.float64) if scaler.with_std else None
    start = np.concatenate(([0], np.cumsum(n_sv)[:-1]))
    pairs = [(i, j) for i in range(K) for j in range(i + 1, K)]
    coef = np.zeros((len(sv), len(pairs)))
    conf = np.zeros((len(pairs), K))
    vote_i = np.zeros((len(pairs), K))
    vote_j = np.zeros((len(pairs), K))
    for p, (i, j) in enumerate(pairs):
        si, sj = slice(start[i], start[i] + n_sv[i]), slice(start[j], start[j] + n_sv[j])
        coef[si, p] = dual[j - 1, si]
        coef[sj, p] = dual[i, sj]
        conf[p, i], conf[p, j] = 1.0, -1.0  # sum of confidences: -= -ovo for i, += -ovo for j
        vote_i[p, i] = vote_j[p, j] = 1.0  # ovo >= 0 votes for i, ovo < 0 for j
    columns = None
    if isinstance(features, FeatureSet):
        columns = np.flatnonzero(mask) if mask is not None else np.arange(d)
    compiled = _CompiledSVM(
        columns=columns, n_features=d, n_classes=K, mean=mean,
        scale=scale, sv_t_m2=np.ascontiguousarray(-2.0 * sv.T), sv_sq=_add(sv * sv, axis=1),
        gamma=float(svc._gamma), coef=coef,
        intercept=np.asarray(svc._intercept_, dtype=np.float64), conf=conf,
        vote_diff=vote_i - vote_j, vote_base=vote_j.sum(axis=0),
        neg_a=-np.asarray([float(c.a_) for c in cals]), neg_b=-np.asarray([float(c.b_) for c in cals]))
    return compiled if _agrees_with_sklearn(compiled, model, sv, mean, scale) else None


def _agrees_with_sklearn(c: "_CompiledSVM", model, sv: np.ndarray, mean, scale) -> bool:
    """One-time check of the transcription against the installed sklearn: probabilities at
    probe points (support vectors and midpoints between them, in feature units) within 1e-9.
    Guards against a sklearn release that changes any step (then sklearn keeps predicting)."""
    k = min(len(sv), 16)
    Z = np.concatenate((sv[:k], 0.5 * (sv[:k] + sv[::-1][:k]), 0.5 * sv[:k]))
    F = Z * (1.0 if scale is None else scale) + (0.0 if mean is None else mean)
    try:
        ref = model.predict_proba(F)
        ours = _calibrated_proba(c, _decision(c, F))
    except Exception:  # noqa: BLE001 - any failure means: do not use the fast path
        return False
    return ref.shape == ours.shape and bool(np.all(np.abs(ref - ours) <= 1e-9))


def _ovo_decision(c: _CompiledSVM, Z: np.ndarray) -> np.ndarray:
    """libsvm's one-vs-one decision values of standardised features Z (n, d): (n, P)."""
    n = len(Z)
    out = np.empty((n, c.coef.shape[1]))
    step = max(1, KERNEL_CHUNK_ELEMENTS // max(1, len(c.sv_sq)))
    for i in range(0, n, step):
        z = Z[i:i + step]
        # |z - s|^2 = -2 z.s + |s|^2 + |z|^2, clipped at 0 (rounding next to a support vector)
        sq = z @ c.sv_t_m2
        sq += c.sv_sq
        sq += _add(z * z, axis=1)[:, None]
        np.maximum(sq, 0.0, out=sq)
        sq *= -c.gamma
        out[i:i + step] = np.exp(sq, out=sq) @ c.coef
    out += c.intercept
    return out


def _decision(c: _CompiledSVM, F: np.ndarray) -> np.ndarray:
    """``SVC.decision_function`` of the scaled features: (n, K) one-vs-rest, (n,) when binary."""
    Z = F
    if c.mean is not None:
        Z = Z - c.mean
    if c.scale is not None:
        Z = Z / c.scale
    ovo = _ovo_decision(c, Z)
    if c.n_classes == 2:
        return -ovo[:, 0]  # sklearn flips the sign of a binary libsvm model
    # sklearn.utils.multiclass._ovr_decision_function(ovo < 0, -ovo, K): votes plus the summed
    # confidences squashed into (-1/3, 1/3)
    votes = c.vote_base + (ovo >= 0) @ c.vote_diff
    conf = ovo @ c.conf
    return votes + conf / (3 * (np.abs(conf) + 1))


def _calibrated_proba(c: _CompiledSVM, d: np.ndarray) -> np.ndarray:
    """``_CalibratedClassifier.predict_proba`` (sigmoid) from decision values d."""
    if c.n_classes == 2:
        p1 = expit(c.neg_a[0] * d + c.neg_b[0])  # = expit(-(a d + b)), exactly
        proba = np.stack((1.0 - p1, p1), axis=1)
    else:
        proba = expit(c.neg_a * d + c.neg_b)
        den = _add(proba, axis=1)[:, None]
        if (den != 0).all():
            proba /= den
        else:
            proba = np.divide(proba, den, out=np.full_like(proba, 1.0 / c.n_classes), where=den != 0)
    if proba.max() > 1.0:
        proba[(1.0 < proba) & (proba <= 1.0 + 1e-5)] = 1.0
    return proba


class SVMClassifier(ClassifierMixin, BaseEstimator):
    """Features -> StandardScaler -> RBF SVC (balanced), tuned by grouped search, calibrated.

    Parameters
    ----------
    features : FeatureSet or None
        Feature transformer (None: ``FeatureSet()`` with the reference robot's constants; use
        ``FeatureSet.for_robot(robot, subset)``).
    C_grid : sequence of float, SVC C values searched.
    gamma_grid : sequence of float or "scale", SVC gamma values searched.
    inner_folds : int >= 2, folds of the inner grouped search and calibration.
    random_state : int, seed of the inner splits (and of nothing else: SVC is deterministic).
    n_jobs : int or None, joblib jobs of the inner search.
    select_features : bool, default True, tree-importance feature selection before the SVM.
    selector_trees : int, default 300, trees of the selector's ExtraTreesClassifier.

    Attributes
    ----------
    classes_ : ndarray (K,), labels seen in fit.
    channel_names_ : list of str.
    features_ : fitted FeatureSet.
    feature_mask_ : ndarray of bool (n_features,), features kept by the selection.
    best_params_ : dict, chosen ``C`` and ``gamma``.
    inner_score_ : float, inner CV balanced accuracy of the chosen parameters.
    model_ : CalibratedClassifierCV over the tuned pipeline.
    fit_time_s_ : float.
    """

    def __init__(self, features: FeatureSet | None = None, C_grid: Sequence[float] = DEFAULT_C,
                 gamma_grid: Sequence = DEFAULT_GAMMA, inner_folds: int = 3, random_state: int = 0,
                 n_jobs: int | None = None, select_features: bool = True, selector_trees: int = 300):
        self.features = features
        self.select_features = select_features
        self.selector_trees = selector_trees
        self.C_grid = C_grid
        self.gamma_grid = gamma_grid
        self.inner_folds = inner_folds
        self.random_state = random_state
        self.n_jobs = n_jobs

    def _pipeline(self) -> Pipeline:
        return Pipeline([("scale", StandardScaler()),
                         ("svc", SVC(kernel="rbf", class_weight="balanced"))])

    def fit(self, X, y, groups=None, channel_names: Sequence[str] | None = None):
        """Fit on raw windows.

        Parameters
        ----------
        X : Windows or ndarray (n, C, T).
        y : array (n,), class labels.
        groups : array (n,) or None, run ids (inner splits never split a run); a ``Windows``
            input without ``groups`` uses its run ids.
        channel_names : names of the C channels when X is a plain array.
        """
        t0 = time.perf_counter()
        if groups is None and hasattr(X, "groups"):
            groups = X.groups
        fs = clone(self.features) if self.features is not None else FeatureSet()
        if channel_names is not None:
            fs.set_params(channel_names=tuple(channel_names))
        self._check_params()
        return self._fit_on(fs.fit_transform(X), y, groups, fs, t0)

    def fit_features(self, F: np.ndarray, y, groups, features) -> "SVMClassifier":
        """Fit on the feature matrix ``F`` (n, n_features) of n windows, computed elsewhere.

        The same model as :meth:`fit` on the windows: ``features`` is the fitted, stateless
        feature transformer whose ``transform`` of those windows gives ``F`` (it becomes
        ``features_``, so the fitted model predicts on raw windows). The nested selection
        (:mod:`terrainml.pipeline.select`) computes every spec's features once and fits every
        fold's model on rows of them.
        """
        t0 = time.perf_counter()
        self._check_params()
        return self._fit_on(np.asarray(F, dtype=float), y, groups, features, t0)

    def _check_params(self) -> None:
        if int(self.inner_folds) < 2:
            raise ValueError("SVMClassifier: inner_folds must be >= 2")
        if not len(self.C_grid) or not len(self.gamma_grid):
            raise ValueError("SVMClassifier: C_grid and gamma_grid must not be empty")

    def _fit_on(self, F: np.ndarray, y, groups, fs, t0: float) -> "SVMClassifier":
        y = np.asarray(y)
        if len(y) != len(F):
            raise ValueError(f"SVMClassifier: {len(F)} windows but {len(y)} labels")
        classes = np.unique(y)
        if len(classes) < 2:
            raise ValueError(f"SVMClassifier: need at least 2 classes, got {classes.tolist()}")
        seed = int(self.random_state) if self.random_state is not None else 0
        mask = self._selection_mask(F, y, seed)
        F = F[:, mask]
        splits = inner_splits(y, groups, int(self.inner_folds), seed)
        Cs = [float(c) for c in self.C_grid]
        gammas = [g if isinstance(g, str) else float(g) for g in self.gamma_grid]
        if max(len(tr) for tr, _ in splits) <= KERNEL_SEARCH_MAX_WINDOWS:
            best, best_score = _kernel_search(F, y, splits, Cs, gammas)
        else:  # the kernel matrices would not fit in memory: sklearn's search, kernel on the fly
            search = GridSearchCV(self._pipeline(), {"svc__C": Cs, "svc__gamma": gammas},
                                  scoring="balanced_accuracy", cv=splits, n_jobs=self.n_jobs, refit=False,
                                  error_score="raise")
            with warnings.catch_warnings():  # inner folds may miss a class: sklearn warns per split
                warnings.simplefilter("ignore", UserWarning)
                search.fit(F, y)
            best = {k.split("__", 1)[1]: v for k, v in search.best_params_.items()}
            best_score = float(search.best_score_)
        base = self._pipeline().set_params(**{f"svc__{k}": v for k, v in best.items()})
        model = CalibratedClassifierCV(base, method="sigmoid", cv=splits, ensemble=False)
        model.fit(F, y)
        self.features_ = fs
        self.feature_mask_ = mask
        self.channel_names_ = list(fs.channel_names_)
        self.classes_ = model.classes_
        self.best_params_ = best
        self.inner_score_ = best_score
        self.model_ = model
        self.fit_time_s_ = time.perf_counter() - t0
        return self

    def _selection_mask(self, F: np.ndarray, y: np.ndarray, seed: int) -> np.ndarray:
        """Boolean mask of the features kept (all when ``select_features`` is False)."""
        if not self.select_features:
            return np.ones(F.shape[1], dtype=bool)
        if int(self.selector_trees) < 1:
            raise ValueError("SVMClassifier: selector_trees must be >= 1")
        forest = ExtraTreesClassifier(n_estimators=int(self.selector_trees), class_weight="balanced",
                                      random_state=seed, n_jobs=self.n_jobs)
        forest.fit(np.nan_to_num(F), y)
        imp = forest.feature_importances_
        mask = imp > imp.mean()
        return mask if mask.any() else np.ones(F.shape[1], dtype=bool)

    def transform_features(self, X) -> np.ndarray:
        """The fitted (selected) feature matrix of X, shape (n, n_selected_features)."""
        check_is_fitted(self, "model_")
        F = self.features_.transform(X)
        mask = getattr(self, "feature_mask_", None)
        return F if mask is None else F[:, mask]

    def _compiled(self) -> _CompiledSVM | None:
        """The numpy form of the fitted model (built on first use, rebuilt after a refit)."""
        if getattr(self, "model_", None) is None:
            raise NotFittedError("This SVMClassifier instance is not fitted yet. Call 'fit' first.")
        mask = getattr(self, "feature_mask_", None)
        c = self.__dict__.get("_compiled_svm")
        if c is None or c[0] is not self.model_ or c[1] is not mask or c[2] is not self.features_:
            c = (self.model_, mask, self.features_, _compile_svm(self.model_, mask, self.features_))
            self.__dict__["_compiled_svm"] = c
        return c[3]

    def __getstate__(self):
        state = dict(super().__getstate__())
        state.pop("_compiled_svm", None)  # derived from model_; never persisted
        return state

    def predict_proba(self, X) -> np.ndarray:
        """Calibrated probabilities, shape (n_windows, K), columns in ``classes_`` order.

        The same numbers as ``model_.predict_proba(transform_features(X))`` (tests check to
        1e-12 against sklearn), computed by the numpy form of the fitted pipeline (see the
        module docstring): sklearn's generic path validates its input at every step and costs
        more than the SVM itself when the stream classifies one window at a time.
        """
        return self.predict_proba_and_features(X)[0]

    def predict_proba_and_features(self, X) -> tuple[np.ndarray, np.ndarray]:
        """Probabilities (n, K) of windows X and the selected features (n, d) they came from.

        The features are computed once, as :meth:`predict_proba` computes them: with the numpy
        form of a model on a ``FeatureSet``, only the selected columns (the same numbers as
        :meth:`transform_features`), otherwise :meth:`transform_features`. Serving hands the
        features on to the novelty score (:func:`terrainml.models.novelty.proba_and_features`).
        """
        c = self._compiled()
        if c is not None and c.columns is not None:  # only the selected features are computed
            F = self.features_._transform_columns(X, c.columns)
        else:
            F = self.transform_features(X)
        return self.predict_proba_from_features(F), F

    def predict_proba_from_features(self, F: np.ndarray) -> np.ndarray:
        """Calibrated probabilities (n, K) of the selected features F (n, d) of n windows.

        ``F`` is what :meth:`transform_features` returns (columns in ``feature_names_`` order);
        the numpy form computes the probabilities when there is one and ``F`` is finite,
        sklearn's pipeline otherwise.
        """
        c = self._compiled()
        if c is None:  # no numpy form (other model shape, or it disagreed with sklearn)
            return self.model_.predict_proba(F)
        if F.ndim != 2 or F.shape[1] != c.n_features:
            raise ValueError(f"SVMClassifier: expected {c.n_features} features per window, got "
                             f"shape {F.shape}")
        if not len(F) or not np.isfinite(F).all():  # sklearn's validation names the problem
            return self.model_.predict_proba(F)
        return _calibrated_proba(c, _decision(c, F))

    def predict(self, X) -> np.ndarray:
        """Most probable class per window (argmax of the calibrated probabilities)."""
        p = self.predict_proba(X)
        return self.classes_[np.argmax(p, axis=1)]

    @property
    def feature_names_(self) -> list[str]:
        """Names of the features the SVM sees (after selection)."""
        check_is_fitted(self, "model_")
        names = [str(s) for s in self.features_.get_feature_names_out()]
        mask = getattr(self, "feature_mask_", None)
        return names if mask is None else [n for n, k in zip(names, mask) if k]
