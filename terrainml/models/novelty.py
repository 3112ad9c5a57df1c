"""Novelty score of a window: how unlike the model's training windows it is.

A closed-set classifier names every window one of its classes, also on ground it never saw
(a model trained without SNOW serves SNOW as ASPHALT at confidence 0.73). :class:`NoveltyScorer`
scores each window by its distance to the training windows in the feature space the model uses
(:func:`model_features`: the SVM's selected features, the trees' side-channel or canonical
features), standardised per feature on the training windows:

* ``knn``: distance to the ``k``-th nearest training window (Euclidean, standardised features);
* ``class_knn``: per known class, the features standardised by that class's own spread, the
  distance to the ``k``-th nearest window of the class; the score is the smallest over classes
  (a window is known when it is typical of at least one class at that class's own scale);
* ``mahalanobis``: Mahalanobis distance to the training mean, Ledoit-Wolf shrunk covariance.

The k-NN distances are exact: a batch goes through sklearn's exact index, the few windows of
serving through :class:`_BoundedSearch` (the same distances, from far fewer references read).

Which one is the default (:data:`DEFAULT_METHOD`) was chosen by measurement (docs/models.md,
"Unknown ground"; ``benchmarks/bench_open_set.py``), as was every fixed setting here; nothing was
chosen on the evaluation's held-out runs.

Only *moving* windows are judged (:data:`MOVING_MPS`, when the windows carry wheel speeds): a
robot standing still or creeping feels the same on any ground, and its windows lie far from every
class (on BorealTC's known held-out runs, 40-48 % of windows are not moving, and they hold most of
the high scores). Serving classifies no window standing still either (the scheduler's
``MIN_MOVE_M``), so a threshold set over all windows was set by windows serving never sees, and
was needlessly high for the moving ones. ``moving_mps`` on the scorer records the gate: a window
is flagged when it moves and its score is over the threshold.

The threshold (:func:`fit_novelty`) is set in inner grouped folds of the training windows only:
the scorer is refit on the training runs of every inner fold and scores the windows of its
held-out runs (known ground, never seen by that scorer); the threshold is the ``1 -
novelty_false_alarm`` quantile of those out-of-fold scores (of the moving ones, with the gate), so about
``novelty_false_alarm`` of a new run on known ground is flagged. The inner folds hold one training run
out at a time (:func:`threshold_splits`): an inner scorer then sees all the training runs but
one, as the final scorer (fitted on all of them) sees a new run. With three inner folds, whose
scorers saw two thirds of the runs, held-out windows lay further from their references than a
new run lies from the final scorer's, and the threshold came out high: it realised 0.9 % false
alarms of moving known windows on BorealTC for a 3 % target (one run out: 1.7 %), 1.0 % on the
simulator's tuning runs (1.2 %), and on runs drawn from known Gaussians (the unit test) about
half the target (one run out: about the target). With few runs per class one run out is still
cautious (an inner scorer has one run of its class fewer than the final one): the realised share
stays under the target (``benchmarks/novelty_calibration_study.py``; docs/models.md, "Unknown
ground").

Persistence (:meth:`NoveltyScorer.save` / :meth:`NoveltyScorer.load`): arrays in one safetensors
file, settings in the model manifest's ``novelty`` entry (:mod:`terrainml.models.artifacts`),
checked against the arrays on load. Nothing is pickled.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from safetensors.numpy import load_file, save_file
from sklearn.base import BaseEstimator, ClassifierMixin, clone
from sklearn.covariance import LedoitWolf
from sklearn.model_selection import GroupKFold, LeaveOneGroupOut
from sklearn.neighbors import NearestNeighbors
from sklearn.utils.validation import check_is_fitted

from terrainml.models.calibration import CalibratedModel
# the target's default and range live in a light module (the CLI shows them in --help)
from terrainml.models.novelty_target import DEFAULT_FALSE_ALARM, check_false_alarm
from terrainml.models.svm import inner_splits

__all__ = ["NoveltyScorer", "NoveltyError", "OpenSetModel", "model_features", "model_feature_names",
           "proba_and_features",
           "fit_novelty", "fit_model_novelty", "threshold_splits", "MAX_THRESHOLD_FOLDS", "novelty_of", "METHODS",
           "DEFAULT_METHOD", "DEFAULT_K",
           "DEFAULT_FALSE_ALARM", "NOVELTY_FILE", "MOVING_MPS", "moving_windows", "moving_mask", "check_false_alarm"]

METHODS = ("knn", "class_knn", "mahalanobis")
DEFAULT_METHOD = "class_knn"
DEFAULT_K = 5
#: the threshold's inner folds hold one training run out at a time up to this many runs; beyond,
#: this many grouped folds (each inner scorer still sees 98 % of the runs)
MAX_THRESHOLD_FOLDS = 50
#: at most this many reference windows per class are kept (evenly spaced, deterministic)
MAX_REFERENCE_PER_CLASS = 2000
NOVELTY_FILE = "novelty.safetensors"
#: m/s: a window's mean wheel rim speed above which it can tell ground apart (not scoring.MOVING_TICK_MPS)
MOVING_MPS = 0.2
_SPEED_CHANNELS = (("speed_left_mps", "speed_right_mps"), ("vx",))
_CLIP = 20.0  # standardised features beyond +-20 sd are clipped (heavy-tailed features)
#: up to this many windows are scored one by one by :class:`_BoundedSearch` (serving scores one
#: window per hop: sklearn's search measured ~120 ms per window on the shared 2-core machine, and
#: 2.7 ms per window for its brute force called per class; larger batches go through sklearn)
_SERVED_MAX = 64
#: dimensions of the projection that bounds the served search (:class:`_BoundedSearch`). Measured
#: on the serving benchmark's model (8 classes x 2000 references x 71 features; 987 windows of a
#: held-out stop-and-go course, thread CPU on the loaded 2-core machine): 8 / 12 / 16 dimensions
#: -> median 0.14 / 0.14 / 0.16 ms, p99 0.49 / 0.24 / 0.34 ms per window (full search 0.45 / 0.81)
_BOUND_DIMS = 12
#: relative slack of the bounded search's comparisons: rounding can only add candidates
_SLACK = 1e-9


class NoveltyError(ValueError):
    """A novelty scorer cannot be fitted, loaded or applied (the message says why)."""


def moving_windows(W, min_speed_mps: float = MOVING_MPS) -> np.ndarray:
    """Boolean (n,): windows whose mean rim speed (side channels; else |vx|) exceeds the line.

    Raises ValueError naming the channels looked for when the windows have no speed channel.
    """
    mask = moving_mask(W, min_speed_mps)
    if mask is None:
        raise ValueError(f"windows have none of the speed channels {_SPEED_CHANNELS} "
                         f"(channels: {list(getattr(W, 'channels', []))})")
    return mask


def moving_mask(W, min_speed_mps: float = MOVING_MPS) -> np.ndarray | None:
    """:func:`moving_windows`, or None when ``W`` has no speed channel (then no window is gated)."""
    channels = list(getattr(W, "channels", None) or [])
    for names in _SPEED_CHANNELS:
        if all(c in channels for c in names):
            X = np.asarray(W.X)
            speed = np.mean([np.abs(X[:, channels.index(c)]).mean(axis=1) for c in names], axis=0)
            return speed > float(min_speed_mps)
    return None


def model_features(model: Any, X) -> np.ndarray:
    """The feature matrix (n, F) a fitted classifier computes for windows ``X``.

    ``SVMClassifier``: its selected features (before its scaler); ``BoostedTrees``: its feature
    transformer's output; ``ProbabilityAverage``: the first member with a feature space. A CNN
    has no hand-made feature space: NoveltyError.
    """
    members = getattr(model, "members_", None)
    if members is not None:
        return model_features(members[_feature_member(members)], X)
    if hasattr(model, "transform_features"):
        return np.asarray(model.transform_features(X), dtype=np.float64)
    feats = getattr(model, "features_", None)
    if feats is not None and hasattr(feats, "transform"):
        return np.asarray(feats.transform(X), dtype=np.float64)
    raise NoveltyError(f"a {type(model).__name__} has no feature space for a novelty score "
                       "(use svm, hgb or an average with one of them)")


def _has_feature_space(model: Any) -> bool:
    return hasattr(model, "transform_features") or hasattr(getattr(model, "features_", None), "transform")


def _feature_member(members: Any) -> int:
    """Index of the first member of an average with a feature space (the novelty's)."""
    for j, m in enumerate(members):
        if _has_feature_space(m):
            return j
    raise NoveltyError("no member of the average has a feature space for a novelty score")


def proba_and_features(model: Any, X) -> tuple[np.ndarray, np.ndarray]:
    """``model.predict_proba(X)`` and the model's features of ``X``, the features computed once.

    The serving path of a model with a novelty scorer: the same probabilities (n, K) as
    ``predict_proba`` and the feature matrix (n, F) of :func:`model_features` (the one the
    model's probabilities were computed from, handed on instead of computed again).
    ``CalibratedModel``: its temperature on the wrapped model's probabilities;
    ``ProbabilityAverage``: the features of the first member with a feature space (the other
    members compute their own, another feature space); ``SVMClassifier``, ``BoostedTrees``:
    their ``predict_proba_and_features``. A CNN has no feature space: NoveltyError.
    """
    if isinstance(model, CalibratedModel):
        p, F = proba_and_features(model.model, X)
        return model.calibrator.transform(p), F
    members = getattr(model, "members_", None)
    if members is not None:
        j = _feature_member(members)
        probas = [m.predict_proba(X) for m in members[:j]]
        p, F = proba_and_features(members[j], X)
        probas += [p] + [m.predict_proba(X) for m in members[j + 1:]]
        return model.mean_proba(probas), F
    if not _has_feature_space(model) or not hasattr(model, "predict_proba_and_features"):
        raise NoveltyError(f"a {type(model).__name__} has no feature space for a novelty score "
                           "(use svm, hgb or an average with one of them)")
    p, F = model.predict_proba_and_features(X)
    return p, np.asarray(F, dtype=np.float64)


def model_feature_names(model: Any) -> list[str]:
    """Names of the features :func:`model_features` returns for ``model`` (same order)."""
    members = getattr(model, "members_", None)
    if members is not None:
        return model_feature_names(members[_feature_member(members)])
    if hasattr(model, "transform_features"):
        return list(model.feature_names_)
    feats = getattr(model, "features_", None)
    if feats is not None and hasattr(feats, "get_feature_names_out"):
        return [str(n) for n in feats.get_feature_names_out()]
    raise NoveltyError(f"a {type(model).__name__} has no feature space for a novelty score")


def _evenly(idx: np.ndarray, n_max: int) -> np.ndarray:
    if len(idx) <= n_max:
        return idx
    return idx[np.linspace(0, len(idx) - 1, n_max).round().astype(int)]


def _principal_axes(R: np.ndarray, dims: int) -> np.ndarray:
    """Orthonormal (F, d) basis of the ``d = min(dims, F)`` leading principal axes of the rows of
    ``R`` (eigenvectors of ``R^T R``, largest eigenvalue first)."""
    _, vecs = np.linalg.eigh(R.T @ R)
    return np.ascontiguousarray(vecs[:, ::-1][:, :min(dims, R.shape[1])])


class _BoundedSearch:
    """Exact smallest k-th neighbour distance of one query over several reference sets.

    For reference set ``j`` (``refs[j]``, (n_j, F)) and its query ``Q[j]`` (F,), :meth:`min_kth`
    returns min over j of the k-th smallest ``|Q[j] - r|`` over the rows r of ``refs[j]``:
    exactly what a brute-force search of every reference computes (each distance from the
    difference, as :meth:`kth` computes it), but the distances only of the few references that
    can be among the k nearest (branch and bound):

    1. at build time the references of each set are projected onto the set's leading principal
       axes (:func:`_principal_axes`, orthonormal ``P_j``, :data:`_BOUND_DIMS` of them):
       ``|P_j^T (q - r)| <= |q - r|`` bounds every distance from below, and one batched product
       gives the bounds of all references of all sets;
    2. the set with the smallest bound is searched first: the k-th exact distance among its 2k
       references of smallest bound is an upper bound ``u`` of its k-th distance, so only its
       references whose bound is ``<= u`` can be among its k nearest;
    3. another set is searched on its references whose bound is ``<= best`` (the smallest k-th
       distance so far), and not at all with fewer than k of them (its k-th distance is larger).

    The comparisons carry a slack of :data:`_SLACK` times the squared norms involved (larger
    than the rounding of the bounds by orders of magnitude): rounding can only add candidates,
    never drop a neighbour. On the serving benchmark's model a window reads about 10 of the
    16,000 references in full (median), the projected 12 columns of all of them once.
    """

    def __init__(self, refs: list[np.ndarray], k: int, dims: int = _BOUND_DIMS):
        self.refs = [np.ascontiguousarray(r, dtype=np.float64) for r in refs]
        self.k = int(k)
        n_max = max(len(r) for r in self.refs)
        self.axes = np.stack([_principal_axes(r, dims) for r in self.refs])  # (K, F, d)
        self.proj = np.zeros((len(self.refs), n_max, self.axes.shape[2]))
        # squared projected norm less the slack; +inf pads a set shorter than the longest
        self.proj_sq = np.full((len(self.refs), n_max), np.inf)
        for j, r in enumerate(self.refs):
            p = r @ self.axes[j]
            self.proj[j, :len(r)] = p
            self.proj_sq[j, :len(r)] = (p * p).sum(axis=1) - _SLACK * (r * r).sum(axis=1)

    def bounds(self, Q: np.ndarray) -> np.ndarray:
        """Squared lower bounds (K, n_max) of the distances of ``Q[j]`` to the references of set
        j, less the slack (``inf`` past the end of a shorter set)."""
        qp = np.matmul(Q[:, None, :], self.axes)[:, 0]  # (K, d)
        q_sq = (qp * qp).sum(axis=1) - _SLACK * (Q * Q).sum(axis=1)
        return self.proj_sq - 2.0 * np.matmul(self.proj, qp[:, :, None])[:, :, 0] + q_sq[:, None]

    def kth(self, j: int, q: np.ndarray, idx: np.ndarray) -> float:
        """The k-th smallest distance of ``q`` to the references ``idx`` of set ``j``."""
        d = np.sqrt(((self.refs[j][idx] - q) ** 2).sum(axis=1))
        return float(np.partition(d, self.k - 1)[self.k - 1])

    def min_kth(self, Q: np.ndarray) -> float:
        """min over j of the k-th smallest distance of ``Q[j]`` (row j of (K, F)) to set j."""
        lb = self.bounds(Q)
        first = lb.min(axis=1)
        j0 = int(np.argmin(first))
        m = min(2 * self.k, len(self.refs[j0]))
        u = self.kth(j0, Q[j0], np.argpartition(lb[j0], m - 1)[:m])
        best = self.kth(j0, Q[j0], np.flatnonzero(lb[j0] <= u * u * (1.0 + _SLACK)))
        for j in np.argsort(first).tolist():
            b2 = best * best * (1.0 + _SLACK)
            if first[j] > b2:  # sets in increasing order of their smallest bound: none left
                break
            if j == j0:
                continue
            cand = np.flatnonzero(lb[j] <= b2)
            if len(cand) >= self.k:  # fewer: its k-th distance is above best
                best = min(best, self.kth(j, Q[j], cand))
        return best


class NoveltyScorer:
    """Distance of windows to the training windows in a model's feature space.

    Parameters
    ----------
    method : one of :data:`METHODS`.
    k : int >= 1, neighbour rank of the ``knn`` / ``class_knn`` distance.
    threshold : float or None, scores above it are flagged unknown (set by :func:`fit_novelty`).
    moving_mps : float or None, only windows whose mean rim speed exceeds it are flagged (set by
        :func:`fit_novelty` when the windows carry wheel speeds; None: every window can be).

    Attributes (after :meth:`fit`)
    ------------------------------
    center_, scale_ : ndarray (F,), per-feature mean and standard deviation of the training
        windows. reference_ : ndarray (m, F), standardised reference windows; reference_y_ (m,).
    class_center_, class_scale_ : ndarray (K, F) (``class_knn``). classes_ : ndarray (K,).
    precision_, mean_ : Mahalanobis precision (F, F) and mean (F,) (``mahalanobis``).
    """

    def __init__(self, method: str = DEFAULT_METHOD, k: int = DEFAULT_K, threshold: float | None = None,
                 moving_mps: float | None = None):
        if method not in METHODS:
            raise NoveltyError(f"unknown novelty method {method!r}; expected one of {METHODS}")
        if int(k) < 1:
            raise NoveltyError("novelty k must be >= 1")
        self.method, self.k, self.threshold = method, int(k), threshold
        self.moving_mps = None if moving_mps is None else float(moving_mps)

    # ------------------------------------------------------------------ fit / score
    def fit(self, F: np.ndarray, y: np.ndarray) -> "NoveltyScorer":
        """Fit on training features ``F`` (n, F) with labels ``y`` (n,)."""
        F = self._check(F, fitted=False)
        y = np.asarray(y)
        self.center_ = F.mean(axis=0)
        sd = F.std(axis=0)
        self.scale_ = np.where(sd > 1e-12, sd, 1.0)
        Z = self._standardise(F)
        self.classes_ = np.unique(y)
        keep = np.concatenate([_evenly(np.flatnonzero(y == c), MAX_REFERENCE_PER_CLASS) for c in self.classes_])
        if any((y == c).sum() <= self.k for c in self.classes_):
            raise NoveltyError(f"novelty: every class needs more than k={self.k} training windows")
        self.reference_, self.reference_y_ = Z[keep], y[keep]
        if self.method == "class_knn":
            self.class_center_ = np.stack([Z[y == c].mean(axis=0) for c in self.classes_])
            csd = np.stack([Z[y == c].std(axis=0) for c in self.classes_])
            self.class_scale_ = np.maximum(csd, 1e-3)
        if self.method == "mahalanobis":
            lw = LedoitWolf().fit(Z)
            self.mean_, self.precision_ = lw.location_, lw.precision_
        self._index = self._bounded = None
        return self

    def _standardise(self, F: np.ndarray) -> np.ndarray:
        return np.clip((F - self.center_) / self.scale_, -_CLIP, _CLIP)

    def _check(self, F, fitted: bool = True) -> np.ndarray:
        F = np.asarray(F, dtype=np.float64)
        if F.ndim != 2 or not len(F):
            raise NoveltyError(f"novelty: features must be a non-empty (n, F) matrix, got shape {F.shape}")
        if fitted and F.shape[1] != len(self.center_):
            raise NoveltyError(f"novelty: expected {len(self.center_)} features per window, got {F.shape[1]}")
        return np.nan_to_num(F, nan=0.0, posinf=0.0, neginf=0.0)

    def _reference_sets(self) -> list[np.ndarray]:
        """The references of each search, in its scale: per class (``class_knn``), or all."""
        if self.method == "class_knn":
            return [(self.reference_[self.reference_y_ == c] - self.class_center_[j]) / self.class_scale_[j]
                    for j, c in enumerate(self.classes_)]
        return [self.reference_]

    def _queries(self, Z: np.ndarray, j: int) -> np.ndarray:
        """Standardised windows ``Z`` (n, F) in the scale of search ``j`` (class j's for
        ``class_knn``; ``Z`` itself for ``knn``'s one search)."""
        if self.method == "class_knn":
            return (Z - self.class_center_[j]) / self.class_scale_[j]
        return Z

    def _window_queries(self, z: np.ndarray) -> np.ndarray:
        """One standardised window ``z`` (F,) in the scale of every search: (K, F)."""
        if self.method == "class_knn":
            return (z - self.class_center_) / self.class_scale_
        return z[None]

    def _search(self) -> _BoundedSearch:
        """The exact bounded search of a few windows (serving), built on first use."""
        if getattr(self, "_bounded", None) is None:
            self._bounded = _BoundedSearch(self._reference_sets(), self.k)
        return self._bounded

    def prepare_serving(self) -> "NoveltyScorer":
        """Build the search that scores a few windows at a time now (else the first
        :meth:`score` of up to :data:`_SERVED_MAX` windows builds it: 50-130 ms on the serving
        benchmark's model, which serving keeps out of its first classification tick)."""
        if getattr(self, "center_", None) is None:
            raise NoveltyError("novelty: the scorer is not fitted (fit or load it first)")
        if self.method != "mahalanobis":
            self._search()
        return self

    def _neighbours(self) -> list:
        """sklearn's exact index of each search (batches of more than :data:`_SERVED_MAX`)."""
        if getattr(self, "_index", None) is None:
            self._index = [NearestNeighbors(n_neighbors=self.k).fit(r) for r in self._reference_sets()]
        return self._index

    def score(self, F: np.ndarray) -> np.ndarray:
        """Novelty score per window, shape (n,) (larger: less like the training windows)."""
        Z = self._standardise(self._check(F))
        if self.method == "mahalanobis":
            d = Z - self.mean_
            return np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", d, self.precision_, d), 0.0))
        # knn: one search; class_knn: one per class in its scale, the score is the smallest
        if len(Z) <= _SERVED_MAX:  # a few windows (serving): exact bounded search, window by window
            search = self._search()
            return np.array([search.min_kth(self._window_queries(z)) for z in Z])
        return np.min([nn.kneighbors(self._queries(Z, j))[0][:, -1] for j, nn in enumerate(self._neighbours())],
                      axis=0)

    def flag(self, scores: np.ndarray, moving: np.ndarray | None = None) -> np.ndarray:
        """Boolean (n,) flags of scores (n,): over the threshold and, when gated, moving.

        NoveltyError when the scorer is gated and ``moving`` is not given (a window's speed
        decides whether it can be flagged)."""
        if self.threshold is None:
            raise NoveltyError("novelty: no threshold set (fit it with fit_novelty)")
        over = np.asarray(scores, dtype=np.float64) > float(self.threshold)
        if self.moving_mps is None:
            return over
        if moving is None:
            raise NoveltyError(f"novelty: the score is gated on moving windows (rim speed > {self.moving_mps} "
                               "m/s); pass each window's moving flag")
        return over & np.asarray(moving, dtype=bool)

    # ------------------------------------------------------------------ persistence
    def _arrays(self) -> dict[str, np.ndarray]:
        a = {"center": self.center_, "scale": self.scale_, "reference": self.reference_,
             "reference_y": np.asarray(self.reference_y_, dtype=np.int64),
             "classes": np.asarray(self.classes_, dtype=np.int64)}
        if self.method == "class_knn":
            a.update(class_center=self.class_center_, class_scale=self.class_scale_)
        if self.method == "mahalanobis":
            a.update(mean=self.mean_, precision=self.precision_)
        return {k: np.ascontiguousarray(v) for k, v in a.items()}

    def config(self) -> dict:
        """JSON-able settings (the manifest's ``novelty`` entry, with the caller's fields)."""
        return {"method": self.method, "k": self.k, "threshold": self.threshold, "moving_mps": self.moving_mps,
                "n_features": int(len(self.center_)), "n_reference": int(len(self.reference_)),
                "classes": [int(c) for c in self.classes_]}

    def save(self, directory: str | Path) -> Path:
        """Write the arrays to ``directory/novelty.safetensors``; returns the path."""
        path = Path(directory) / NOVELTY_FILE
        path.parent.mkdir(parents=True, exist_ok=True)
        save_file(self._arrays(), str(path))
        return path

    @classmethod
    def load(cls, path: str | Path, config: dict) -> "NoveltyScorer":
        """Rebuild from the safetensors file and the manifest entry; NoveltyError names the file
        when an array is missing or disagrees with the entry (shapes, classes)."""
        path = Path(path)
        try:
            a = load_file(str(path))
            s = cls(str(config["method"]), int(config["k"]), config.get("threshold"), config.get("moving_mps"))
        except (KeyError, TypeError) as exc:
            raise NoveltyError(f"{path}: novelty entry of the manifest lacks {exc}") from None
        except Exception as exc:  # noqa: BLE001 - safetensors raises its own error types
            raise NoveltyError(f"{path}: not a readable novelty file ({type(exc).__name__}: {exc})") from None
        need = set(s._arrays_names())
        if need - set(a):
            raise NoveltyError(f"{path}: arrays {sorted(need - set(a))} missing")
        n_f, n_ref = int(config.get("n_features", -1)), int(config.get("n_reference", -1))
        if a["center"].shape != (n_f,) or a["scale"].shape != (n_f,) or a["reference"].shape != (n_ref, n_f):
            raise NoveltyError(f"{path}: array shapes differ from the manifest's novelty entry "
                               f"({n_f} features, {n_ref} reference windows)")
        if a["classes"].tolist() != [int(c) for c in config.get("classes", [])]:
            raise NoveltyError(f"{path}: classes {a['classes'].tolist()} differ from the manifest's")
        if s.threshold is not None and not np.isfinite(float(s.threshold)):
            raise NoveltyError(f"{path}: novelty threshold {s.threshold!r} is not finite")
        s.center_, s.scale_, s.reference_ = a["center"], a["scale"], a["reference"]
        s.reference_y_, s.classes_ = a["reference_y"], a["classes"]
        if s.method == "class_knn":
            s.class_center_, s.class_scale_ = a["class_center"], a["class_scale"]
        if s.method == "mahalanobis":
            s.mean_, s.precision_ = a["mean"], a["precision"]
        s._index = s._bounded = None
        return s

    def _arrays_names(self) -> list[str]:
        extra = {"class_knn": ["class_center", "class_scale"], "mahalanobis": ["mean", "precision"]}
        return ["center", "scale", "reference", "reference_y", "classes", *extra.get(self.method, [])]


def threshold_splits(y, groups, inner_folds: int | None = None, seed: int = 0) -> list:
    """Grouped (train_idx, test_idx) splits whose out-of-fold scores set the threshold.

    ``inner_folds`` None (the default): one run out at a time (``LeaveOneGroupOut``), and with
    more than :data:`MAX_THRESHOLD_FOLDS` runs that many grouped folds (``GroupKFold``), so each
    inner scorer sees all the training runs but one (or 98 % of them). An int: that many
    stratified grouped folds (:func:`~terrainml.models.svm.inner_splits`, seeded).
    """
    y, groups = np.asarray(y), np.asarray(groups)
    if inner_folds is not None:
        return inner_splits(y, groups, int(inner_folds), seed)
    n_runs = len(np.unique(groups))
    if n_runs < 2:
        raise NoveltyError("novelty: the threshold needs at least 2 training runs (one held out at a time)")
    split = LeaveOneGroupOut() if n_runs <= MAX_THRESHOLD_FOLDS else GroupKFold(MAX_THRESHOLD_FOLDS)
    return list(split.split(np.zeros(len(y)), y, groups))


def fit_novelty(F: np.ndarray, y, groups, *, moving: np.ndarray | None = None, method: str = DEFAULT_METHOD,
                k: int = DEFAULT_K, novelty_false_alarm: float = DEFAULT_FALSE_ALARM, inner_folds: int | None = None,
                seed: int = 0) -> tuple[NoveltyScorer, dict]:
    """Fit a scorer on training features and set its threshold in inner grouped folds.

    Parameters
    ----------
    F : ndarray (n, F), the model's features of the training windows (:func:`model_features`).
    y : array (n,), labels. groups : array (n,), run ids (an inner fold never splits a run).
    moving : bool (n,) or None, the moving windows (:func:`moving_mask`): given, the threshold is
        set on the moving held-out windows only and the scorer gets the gate ``moving_mps``.
    method, k : see :class:`NoveltyScorer`.
    novelty_false_alarm : target share of held-out known windows above the threshold, in (0, 0.5).
    inner_folds : None (default, one run out at a time) or a number of grouped folds
        (:func:`threshold_splits`). seed : seed of numbered folds.

    Returns
    -------
    (scorer fitted on all of ``F`` with its ``threshold``, info dict: ``false_alarm_target``,
    ``inner_folds`` (the number of folds used), ``inner_scores_n``, ``seed``).
    """
    check_false_alarm(novelty_false_alarm)
    F = np.asarray(F, dtype=np.float64)
    y, groups = np.asarray(y), np.asarray(groups)
    judged = np.ones(len(y), dtype=bool) if moving is None else np.asarray(moving, dtype=bool)
    oof, splits = [], threshold_splits(y, groups, inner_folds, seed)
    for tr, te in splits:
        # a class absent from the inner training is not "known"; a window standing still is not judged
        known = np.isin(y[te], np.unique(y[tr])) & judged[te]
        if known.any() and all((y[tr] == c).sum() > k for c in np.unique(y[tr])):
            oof.append(NoveltyScorer(method, k).fit(F[tr], y[tr]).score(F[te][known]))
    if not oof:
        raise NoveltyError("novelty: no inner fold tests a known class" + ("" if moving is None else " moving")
                           + " (too few runs per class)")
    oof = np.concatenate(oof)
    scorer = NoveltyScorer(method, k, moving_mps=None if moving is None else MOVING_MPS).fit(F, y)
    scorer.threshold = float(np.quantile(oof, 1.0 - float(novelty_false_alarm)))
    return scorer, {"false_alarm_target": float(novelty_false_alarm), "inner_folds": len(splits),
                    "inner_scores_n": int(len(oof)), "seed": int(seed)}


def novelty_of(model: Any, scorer: NoveltyScorer, X) -> np.ndarray:
    """Novelty scores (n,) of windows ``X`` for a fitted model and its scorer."""
    return scorer.score(model_features(model, X))


class OpenSetModel(ClassifierMixin, BaseEstimator):
    """A classifier with the novelty score of its windows, fitted together (open-set evaluation).

    ``fit`` fits a clone of ``base`` and then :func:`fit_novelty` on the fitted model's features
    of the same training windows (threshold from inner grouped folds of them). ``predict_proba``
    is the base model's; ``novelty_score`` the scorer's.

    Parameters
    ----------
    base : unfitted classifier with a feature space (:func:`model_features`).
    method, k, novelty_false_alarm, inner_folds : see :func:`fit_novelty`. random_state : seed of the
        inner folds.

    Attributes
    ----------
    model_ : fitted base. scorer_ : fitted NoveltyScorer. novelty_threshold_ : float.
    novelty_info_ : dict. classes_ : ndarray (K,).
    """

    def __init__(self, base: Any = None, method: str = DEFAULT_METHOD, k: int = DEFAULT_K,
                 novelty_false_alarm: float = DEFAULT_FALSE_ALARM, inner_folds: int | None = None, random_state=0):
        self.base = base
        self.method = method
        self.k = k
        self.novelty_false_alarm = novelty_false_alarm
        self.inner_folds = inner_folds
        self.random_state = random_state

    def fit(self, X, y, groups=None):
        """Fit on windows ``X``, labels ``y`` (n,) and run ids ``groups`` (n,)."""
        if self.base is None:
            raise NoveltyError("OpenSetModel: no base classifier")
        groups = np.asarray(groups if groups is not None else getattr(X, "groups", np.arange(len(y))))
        self.model_ = clone(self.base)
        self.model_.fit(X, y, groups=groups)
        self.scorer_, self.novelty_info_ = fit_novelty(
            model_features(self.model_, X), y, groups, moving=moving_mask(X), method=self.method, k=self.k,
            novelty_false_alarm=self.novelty_false_alarm, inner_folds=self.inner_folds, seed=self.random_state)
        self.novelty_threshold_ = float(self.scorer_.threshold)
        self.classes_ = np.asarray(self.model_.classes_)
        return self

    def predict_proba(self, X) -> np.ndarray:
        check_is_fitted(self, "model_")
        return self.model_.predict_proba(X)

    def predict(self, X) -> np.ndarray:
        return self.classes_[np.argmax(self.predict_proba(X), axis=1)]

    def novelty_score(self, X) -> np.ndarray:
        """Novelty score per window (n,) (above ``novelty_threshold_``: unknown ground)."""
        check_is_fitted(self, "scorer_")
        return novelty_of(self.model_, self.scorer_, X)


def fit_model_novelty(model: Any, W, seed: int = 0, **kwargs: Any) -> tuple[NoveltyScorer, dict]:
    """:func:`fit_novelty` on a fitted model's features of its training windows ``W`` (labels
    ``W.y``, runs ``W.groups``, moving windows :func:`moving_mask` of its wheel speeds);
    ``kwargs`` as there. NoveltyError for a model without a feature space (a CNN)."""
    return fit_novelty(model_features(model, W), W.y, W.groups, moving=moving_mask(W), seed=seed, **kwargs)
