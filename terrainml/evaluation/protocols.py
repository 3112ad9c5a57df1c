"""Two evaluation protocols for real terrain data sets (BorealTC and alike), as reusable functions.

Protocol (a), *the authors' protocol* (LaRocque et al., IROS 2024, BorealTC ``main.py`` /
``utils/preprocessing.py``), for a like-for-like comparison with their published numbers:

1. every run is cut into non-overlapping **5-s chunks** from its first IMU sample (an incomplete
   tail is dropped; a chunk with any invalid IMU/wheel/current sample is dropped and counted);
2. the chunks are split by ``StratifiedKFold(5, shuffle=True)`` on the chunk labels, *not*
   grouped by run: chunks of one run fall into training and test folds;
3. inside every chunk, **1.7-s windows** are cut. ``homogeneous=True`` reproduces the authors'
   class balancing ("homogeneous augmentation"): the smallest class gets
   ``max_windows_per_chunk`` windows per chunk (33 = a 0.1-s stride in the authors' code), every
   other class ``int(max_windows_per_chunk * n_chunks(smallest) / n_chunks(class))`` windows per
   chunk, evenly spaced, so that every class has about the same number of windows (in training
   *and* in test). Accuracy over windows is then close to the balanced accuracy.

Protocol (b), *grouped by run*: the same windows, ``StratifiedGroupKFold(5, shuffle=True)``
with the run id as group, so no run is in both training and test: the figure a new run on a
known terrain can expect.

Hyper-parameters are never tuned on a test fold: :func:`evaluate_protocol` passes the inner
groups (chunk ids in (a), run ids in (b)) to the model's ``fit``, whose own inner search splits
by them (``SVMClassifier`` grid search, ``CNNClassifier`` early stopping).

:class:`SideChannelFeatures` is the feature transformer for robots without camera or steering
(BorealTC's raw channels: IMU, and per-side motor currents and speeds). *Departure*: it lives
here rather than in :mod:`terrainml.features.sets` because :class:`~terrainml.features.sets.
FeatureSet` is built around the canonical slip/vx/vy/r channels, which a camera-less robot lacks.

Departures from the authors' pipeline (documented in ``docs/borealtc.md``): our run tables are
resampled to 100 Hz by linear interpolation (the authors keep the 6.5 Hz wheel service as a
separate, nearest-sample stream); runs without an IMU file have no 5-s chunks in either
protocol (the authors' chunking is driven by the IMU stream, so they drop them too).
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np
import pandas as pd
from joblib import Parallel, delayed
from scipy.signal import welch
from sklearn.base import BaseEstimator, ClassifierMixin, TransformerMixin
from sklearn.model_selection import StratifiedGroupKFold, StratifiedKFold
from sklearn.utils.validation import check_is_fitted

from terrainml.features.windows import Windows
from terrainml.evaluation.cv import check_no_shared_runs
from terrainml.evaluation.metrics import classification_metrics

__all__ = [
    "SIDE_CHANNELS", "ChunkSet", "make_chunks", "chunk_windows", "protocol_a_folds",
    "protocol_b_folds", "check_groups_not_split", "evaluate_protocol", "ProtocolResult", "average_results",
    "SideChannelFeatures", "side_channel_features", "AuthorsSVM", "BoostedTrees", "protocol_models",
]

#: raw channels of a skid-steer robot without camera: window channel name -> run-table column.
#: ``current_left``/``speed_left_mps`` come from wheel 1 (front-left; the Husky's left motor drives
#: wheels 1 and 3), the right side from wheel 2. Speeds are wheel rim speeds omega * R (m/s).
SIDE_CHANNELS: dict[str, str] = {
    "imu_ax": "imu_ax_mps2", "imu_ay": "imu_ay_mps2", "imu_az": "imu_az_mps2",
    "imu_wx": "imu_roll_rate_radps", "imu_wy": "imu_pitch_rate_radps", "imu_wz": "imu_yaw_rate_radps",
    "current_left": "wheel1_current_a", "current_right": "wheel2_current_a",
    "speed_left_mps": "wheel1_omega_radps", "speed_right_mps": "wheel2_omega_radps",
}
_VALID_COLS = ("imu_valid", "wheels_valid", "current_valid")


# ------------------------------------------------------------------------------------ chunks
@dataclass
class ChunkSet:
    """Non-overlapping chunks of the runs.

    Attributes
    ----------
    meta : DataFrame, one row per chunk: ``chunk_id`` (int, 0..m-1), ``run_id`` (str),
        ``terrain`` (int label), ``table`` (index into the tables list), ``start_index`` (row),
        ``t_start_s`` (s).
    chunk_samples : int, rows per chunk.
    rate_hz : float.
    dropped : dict reason -> number of chunks (or runs) left out.
    runs_without_chunks : list of run ids that gave no chunk (e.g. no IMU file).
    """

    meta: pd.DataFrame
    chunk_samples: int
    rate_hz: float
    dropped: dict = field(default_factory=dict)
    runs_without_chunks: list = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.meta)


def _table_rate_hz(df: pd.DataFrame) -> float:
    rate = (df.attrs.get("terrainml") or {}).get("rate_hz")
    if rate:
        return float(rate)
    return float(1.0 / np.median(np.diff(df["t_s"].to_numpy())))


def make_chunks(tables: Sequence[pd.DataFrame], chunk_s: float = 5.0,
                valid_cols: Sequence[str] = _VALID_COLS) -> ChunkSet:
    """Cut every run table into non-overlapping ``chunk_s`` chunks from its first row.

    Parameters
    ----------
    tables : canonical run tables (one run each; ``terrain`` int label, ``run_id``), same rate.
    chunk_s : chunk length in seconds (5 s in the authors' protocol).
    valid_cols : validity flags that must all be True on every row of a chunk; a chunk with an
        invalid row is dropped and counted (a run without IMU therefore yields no chunk).

    Returns
    -------
    ChunkSet
    """
    if not tables:
        raise ValueError("make_chunks: no run tables")
    if not chunk_s > 0:
        raise ValueError(f"make_chunks: chunk_s must be > 0, got {chunk_s!r}")
    rate = _table_rate_hz(tables[0])
    L = int(round(chunk_s * rate))
    rows, dropped, empty = [], {"invalid samples": 0, "unlabelled": 0}, []
    for k, df in enumerate(tables):
        run_id = str(df["run_id"].iloc[0])
        n = len(df)
        ok = np.ones(n, bool)
        for c in valid_cols:
            if c in df:
                ok &= df[c].to_numpy(dtype=bool)
        labels = df["terrain"].to_numpy()
        n_before = len(rows)
        for s in range(0, n - L + 1, L):
            if not ok[s:s + L].all():
                dropped["invalid samples"] += 1
                continue
            lab = labels[s:s + L]
            if lab[0] < 0 or (lab != lab[0]).any():
                dropped["unlabelled"] += 1
                continue
            rows.append((run_id, int(lab[0]), k, s, float(df["t_s"].iloc[s])))
        if len(rows) == n_before:
            empty.append(run_id)
    meta = pd.DataFrame(rows, columns=["run_id", "terrain", "table", "start_index", "t_start_s"])
    meta.insert(0, "chunk_id", np.arange(len(meta), dtype=np.int64))
    return ChunkSet(meta, L, rate, dropped, empty)


def windows_per_chunk(chunk_terrain: np.ndarray, max_windows_per_chunk: int,
                      homogeneous: bool = True) -> dict[int, int]:
    """Windows cut from each chunk of a class (the authors' homogeneous augmentation).

    The class with the fewest chunks gets ``max_windows_per_chunk``; class k gets
    ``int(max_windows_per_chunk * n_min / n_k)`` (at least 1) so every class has about
    ``max_windows_per_chunk * n_min`` windows. ``homogeneous=False``: every class gets the max.
    """
    labels, counts = np.unique(np.asarray(chunk_terrain), return_counts=True)
    if not homogeneous:
        return {int(c): int(max_windows_per_chunk) for c in labels}
    n_min = counts.min()
    return {int(c): max(1, int(max_windows_per_chunk * n_min / n)) for c, n in zip(labels, counts)}


def chunk_windows(tables: Sequence[pd.DataFrame], chunks: ChunkSet, window_s: float = 1.7,
                  max_windows_per_chunk: int = 33, homogeneous: bool = True,
                  channels: dict[str, str] | None = None, wheel_radius_m: float | None = None) -> Windows:
    """Cut ``window_s`` windows inside every chunk (windows never cross a chunk boundary).

    Parameters
    ----------
    tables : the run tables the chunks were cut from.
    chunks : :func:`make_chunks` output.
    window_s : window length (s); 1.7 s in the authors' headline numbers.
    max_windows_per_chunk : windows per chunk of the smallest class (33 = the authors' 0.1-s
        stride in a 5-s chunk with 1.7-s windows). Starts are evenly spaced with the
        integer stride ``(chunk - window) // n_k`` from the chunk start, as in the authors' code.
    homogeneous : balance the classes (see :func:`windows_per_chunk`).
    channels : window channel name -> run-table column (default :data:`SIDE_CHANNELS`).
    wheel_radius_m : R to turn ``*_omega_radps`` into rim speed for channels named
        ``speed_*_mps`` (default: the robot spec in the table metadata, else 1).

    Returns
    -------
    Windows with X (n, C, T) and meta columns ``run_id, terrain, chunk_id, t_start_s, t_end_s,
    start_index``.
    """
    channels = dict(channels or SIDE_CHANNELS)
    T = int(round(window_s * chunks.rate_hz))
    L = chunks.chunk_samples
    if T > L:
        raise ValueError(f"chunk_windows: window {window_s} s longer than the chunk ({L} samples)")
    if max_windows_per_chunk < 1:
        raise ValueError("chunk_windows: max_windows_per_chunk must be >= 1")
    if wheel_radius_m is None:
        wheel_radius_m = _radius_from_tables(tables)
    per = windows_per_chunk(chunks.meta["terrain"].to_numpy(), max_windows_per_chunk, homogeneous)
    names = list(channels)
    # per table, the channel matrix (C, n) in window units
    mats: dict[int, np.ndarray] = {}
    for k in np.unique(chunks.meta["table"].to_numpy()):
        df = tables[int(k)]
        cols = []
        for name, col in channels.items():
            if col not in df:
                raise KeyError(f"run {df['run_id'].iloc[0]}: column {col!r} (channel {name}) missing")
            x = df[col].to_numpy(dtype=np.float64)
            if name.startswith("speed_") and col.endswith("_omega_radps"):
                x = x * wheel_radius_m
            cols.append(x)
        mats[int(k)] = np.stack(cols)
    X, meta = [], []
    for ch in chunks.meta.itertuples(index=False):
        n_k = per[int(ch.terrain)]
        stride = max(1, (L - T) // n_k) if n_k > 1 else 0
        M = mats[int(ch.table)]
        t0 = float(tables[int(ch.table)]["t_s"].iloc[ch.start_index])
        for j in range(n_k):
            s = int(ch.start_index) + j * stride
            if s + T > int(ch.start_index) + L:
                break
            X.append(M[:, s:s + T])
            meta.append((ch.run_id, int(ch.terrain), int(ch.chunk_id), t0 + j * stride / chunks.rate_hz,
                         t0 + (j * stride + T) / chunks.rate_hz, s))
    meta_df = pd.DataFrame(meta, columns=["run_id", "terrain", "chunk_id", "t_start_s", "t_end_s", "start_index"])
    Xa = np.stack(X) if X else np.zeros((0, len(names), T))
    return Windows(Xa, tuple(names), meta_df, chunks.rate_hz)


def _radius_from_tables(tables) -> float:
    import json

    md = tables[0].attrs.get("terrainml") or {}
    rj = md.get("robot_spec") or md.get("robot_json")
    if rj:
        try:
            d = json.loads(rj) if isinstance(rj, str) else rj
            return float(d["wheel_radius_m"])
        except (ValueError, KeyError, TypeError):
            pass
    return 1.0


# ------------------------------------------------------------------------------------ folds
def protocol_a_folds(windows: Windows, n_splits: int = 5, seed: int = 21) -> list[tuple[np.ndarray, np.ndarray]]:
    """Authors' protocol: stratified K-fold over 5-s chunks (not grouped by run), seeded.

    Every window follows its chunk, so a chunk is never split across folds; chunks of one run
    may be in training and test. Default seed 21 = the authors' ``RANDOM_STATE``.

    Returns
    -------
    list of (train_idx, test_idx) window index arrays.
    """
    meta = windows.meta
    ch = meta.drop_duplicates("chunk_id")[["chunk_id", "terrain"]].sort_values("chunk_id")
    cv = StratifiedKFold(n_splits=int(n_splits), shuffle=True, random_state=int(seed))
    chunk_of = meta["chunk_id"].to_numpy()
    folds = []
    ids = ch["chunk_id"].to_numpy()
    for _, te_c in cv.split(np.zeros(len(ch)), ch["terrain"].to_numpy()):
        te = np.isin(chunk_of, ids[te_c])
        folds.append((np.flatnonzero(~te), np.flatnonzero(te)))
    return folds


def protocol_b_folds(windows: Windows, n_splits: int = 5, seed: int = 0) -> list[tuple[np.ndarray, np.ndarray]]:
    """Grouped protocol: ``StratifiedGroupKFold`` with the run id as group (no run split), seeded."""
    cv = StratifiedGroupKFold(n_splits=int(n_splits), shuffle=True, random_state=int(seed))
    y = windows.meta["terrain"].to_numpy()
    g = windows.meta["run_id"].astype(str).to_numpy()
    return [(np.asarray(tr), np.asarray(te)) for tr, te in cv.split(np.zeros(len(y)), y, g)]


def check_groups_not_split(folds, groups) -> None:
    """AssertionError if a group (a run, or a 5-s chunk under protocol (a)) is in train and test
    of a fold, or in two test parts: :func:`terrainml.evaluation.cv.check_no_shared_runs`."""
    check_no_shared_runs(folds, groups)


# ------------------------------------------------------------------------------- evaluation
@dataclass
class ProtocolResult:
    """Out-of-fold predictions of one model under one protocol.

    Attributes
    ----------
    name : protocol label. classes : labels (K,). class_names : names (K,).
    y_true, y_pred : ndarray (n,). fold_of : ndarray (n,), fold that predicted each window.
    fold_metrics : list of dict (accuracy, balanced_accuracy, fit_time_s, best_params).
    pooled : dict, :func:`~terrainml.evaluation.metrics.classification_metrics` of all
        out-of-fold predictions (accuracy, balanced_accuracy, macro_f1, confusion_matrix with rows
        true and columns predicted, recall_per_class).
    proba : ndarray (n, K) or None, out-of-fold probabilities (columns in ``classes`` order) when
        the model has ``predict_proba`` (then ``y_pred`` is their argmax).
    """

    name: str
    classes: np.ndarray
    class_names: list
    y_true: np.ndarray
    y_pred: np.ndarray
    fold_of: np.ndarray
    fold_metrics: list
    pooled: dict
    proba: np.ndarray | None = None

    @property
    def accuracy(self) -> float:
        return float(self.pooled["accuracy"])

    @property
    def balanced_accuracy(self) -> float:
        return float(self.pooled["balanced_accuracy"])

    def recall_per_class(self) -> dict[str, float]:
        rec = self.pooled["recall_per_class"]
        return {n: float(rec.get(str(c), np.nan)) for c, n in zip(self.classes.tolist(), self.class_names)}

    def precision_per_class(self) -> dict[str, float]:
        cm = np.asarray(self.pooled["confusion_matrix"], float)
        col = cm.sum(axis=0)
        return {n: float(cm[k, k] / col[k]) if col[k] else float("nan") for k, n in enumerate(self.class_names)}

    def confusion_frame(self) -> pd.DataFrame:
        return pd.DataFrame(self.pooled["confusion_matrix"], index=self.class_names, columns=self.class_names)

    def fold_accuracy_std(self) -> float:
        return float(np.std([m["accuracy"] for m in self.fold_metrics]))


def _fit_predict(factory, X, y, inner_groups, tr, te):
    model = factory()
    Xtr = X.subset(tr) if hasattr(X, "subset") else np.asarray(X)[tr]
    Xte = X.subset(te) if hasattr(X, "subset") else np.asarray(X)[te]
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        model.fit(Xtr, y[tr], groups=inner_groups[tr])
    t1 = time.perf_counter()
    proba = None
    if hasattr(model, "predict_proba") and hasattr(model, "classes_"):
        p = np.asarray(model.predict_proba(Xte), dtype=float)
        cls = np.asarray(model.classes_)
        pred = cls[np.argmax(p, axis=1)]
        proba = (cls, p)
    else:
        pred = np.asarray(model.predict(Xte))
    return pred, proba, t1 - t0, dict(getattr(model, "best_params_", {}) or {})


def evaluate_protocol(factory: Callable[[], Any], windows: Windows, folds, *, inner_groups,
                      class_names: Sequence[str] | None = None, name: str = "",
                      split_groups=None, n_jobs: int | None = 1,
                      progress: Callable[[int, int], None] | None = None) -> ProtocolResult:
    """Fit a fresh model per fold and predict the held-out windows.

    Parameters
    ----------
    factory : callable -> unfitted classifier with ``fit(X, y, groups=...)`` and ``predict``.
    windows : Windows (n windows).
    folds : list of (train_idx, test_idx) from :func:`protocol_a_folds` / :func:`protocol_b_folds`.
    inner_groups : array (n,), groups the model's inner search/early stopping must not split
        (chunk ids for protocol (a), run ids for (b)).
    class_names : names of the labels 0..K-1 (default: the label values).
    split_groups : array (n,) or None; when given, checked never to be split by ``folds``.
    n_jobs : joblib jobs over folds (each fold single-threaded inside is best on 2 cores).

    Returns
    -------
    ProtocolResult
    """
    y = windows.meta["terrain"].to_numpy()
    inner_groups = np.asarray(inner_groups)
    if split_groups is not None:
        check_groups_not_split(folds, split_groups)
    classes = np.unique(y)
    names = list(class_names) if class_names is not None else [str(c) for c in classes]
    names = [names[int(c)] if class_names is not None else str(c) for c in classes]
    jobs = [delayed(_fit_predict)(factory, windows, y, inner_groups, tr, te) for tr, te in folds]
    if n_jobs == 1:
        out = []
        for k, j in enumerate(jobs):
            out.append(j[0](*j[1], **j[2]))
            if progress:
                progress(k + 1, len(folds))
    else:
        out = Parallel(n_jobs=n_jobs)(jobs)
    y_pred = np.empty_like(y)
    fold_of = np.full(len(y), -1)
    fold_metrics = []
    col = {c: j for j, c in enumerate(classes.tolist())}
    proba = np.zeros((len(y), len(classes))) if all(o[1] is not None for o in out) else None
    for k, ((tr, te), (pred, pr, fit_s, best)) in enumerate(zip(folds, out)):
        y_pred[te] = pred
        fold_of[te] = k
        if proba is not None:
            for j, c in enumerate(pr[0].tolist()):
                proba[te, col[c]] = pr[1][:, j]
        m = classification_metrics(y[te], pred, None, classes)
        fold_metrics.append({"fold": k, "n_test": int(len(te)), "accuracy": m["accuracy"],
                             "balanced_accuracy": m["balanced_accuracy"], "fit_time_s": float(fit_s),
                             "best_params": best})
    return _result(name, classes, names, y, y_pred, fold_of, fold_metrics, proba)


def _result(name, classes, names, y, y_pred, fold_of, fold_metrics, proba) -> ProtocolResult:
    done = fold_of >= 0
    pooled = classification_metrics(y[done], y_pred[done], None if proba is None else proba[done], classes)
    return ProtocolResult(name, classes, names, y[done], y_pred[done], fold_of[done], fold_metrics, pooled,
                          None if proba is None else proba[done])


def average_results(results: Sequence[ProtocolResult], name: str = "average") -> ProtocolResult:
    """Fixed-rule ensemble: mean of the out-of-fold probabilities of several results.

    The results must come from the same windows and folds (checked) and carry probabilities.
    No weight is tuned, so nothing is learnt from the test folds.
    """
    first = results[0]
    for r in results[1:]:
        if not (np.array_equal(r.y_true, first.y_true) and np.array_equal(r.fold_of, first.fold_of)
                and np.array_equal(r.classes, first.classes)):
            raise ValueError("average_results: results from different windows, folds or classes")
    if any(r.proba is None for r in results):
        raise ValueError("average_results: every result needs out-of-fold probabilities")
    proba = np.mean([r.proba for r in results], axis=0)
    y_pred = first.classes[np.argmax(proba, axis=1)]
    fold_metrics = []
    for k in np.unique(first.fold_of):
        m = first.fold_of == k
        mk = classification_metrics(first.y_true[m], y_pred[m], None, first.classes)
        fold_metrics.append({"fold": int(k), "n_test": int(m.sum()), "accuracy": mk["accuracy"],
                             "balanced_accuracy": mk["balanced_accuracy"],
                             "fit_time_s": float(sum(r.fold_metrics[int(k)]["fit_time_s"] for r in results)),
                             "best_params": {}})
    return _result(name, first.classes, first.class_names, first.y_true, y_pred, first.fold_of,
                   fold_metrics, proba)


# -------------------------------------------------------------------------------- features
IMU_CHANNELS = ("imu_ax", "imu_ay", "imu_az", "imu_wx", "imu_wy", "imu_wz")
ROUGHNESS_MIN_SPEED_MPS = 0.2
BANDS_HZ = ((0.0, 1.0), (1.0, 3.0), (3.0, 6.0), (6.0, 10.0), (10.0, 15.0), (15.0, 20.0),
            (20.0, 30.0), (30.0, 40.0), (40.0, 50.0))


def side_channel_features(X: np.ndarray, channels: Sequence[str], rate_hz: float = 100.0,
                          track_m: float = 0.5708, bands_hz=BANDS_HZ,
                          correlations: bool = True) -> tuple[np.ndarray, list[str]]:
    """Window features for a skid-steer robot's raw side channels.

    Parameters
    ----------
    X : ndarray (n, C, T) in channel units (m/s^2, rad/s, A, m/s).
    channels : C names; the physics features use ``current_left/right``, ``speed_left/right_mps``
        and ``imu_wz`` when present.
    rate_hz : sample rate (Hz). track_m : left-right wheel distance B (m).
    bands_hz : Welch band edges (Hz) for the log band powers of every channel.
    correlations : add the Pearson correlation of every channel pair (C(C-1)/2 features).

    Returns
    -------
    F (n, n_features) float64 and the feature names.

    Features: per channel mean, std, min, max, p10, p50, p90, skew, excess kurtosis, mean
    absolute first difference (jerk proxy), log10 Welch band powers (Hann, nperseg min(64, T))
    and spectral centroid; channel-pair correlations; physics: left-right current difference
    and sum (mean, std), left-right speed difference, forward speed v = (vL + vR)/2, current
    per speed sum(i)/max(|v|, 0.05) per side and total, electrical power proxy i*v per side,
    and the skid indicator: measured yaw rate minus the kinematic one (vR - vL)/B (mean, std)
    and their ratio; roughness invariants for every IMU channel, log10 of std / v^2, std / v
    and mean |first difference| / v, plus log10 of the mean |total current| / v (v the mean
    forward speed floored at 0.2 m/s): vibration grows with speed, these ratios do not, which
    helps a run driven faster than any training run of its class.
    """
    X = np.asarray(X, dtype=np.float64)
    channels = list(channels)
    n, C, T = X.shape
    if C != len(channels):
        raise ValueError(f"features: X has {C} channels, got {len(channels)} names")
    X = np.where(np.isfinite(X), X, np.nanmean(X, axis=2, keepdims=True))
    X = np.nan_to_num(X)
    cols: dict[str, np.ndarray] = {}
    mean = X.mean(axis=2)
    c = X - mean[..., None]
    m2 = (c * c).mean(axis=2)
    std = np.sqrt(m2)
    safe = np.where(m2 > 1e-20, m2, 1.0)
    skew = np.where(m2 > 1e-20, (c ** 3).mean(axis=2) / safe ** 1.5, 0.0)
    kurt = np.where(m2 > 1e-20, (c ** 4).mean(axis=2) / safe ** 2 - 3.0, 0.0)
    p10, p50, p90 = np.percentile(X, [10, 50, 90], axis=2)
    dabs = np.abs(np.diff(X, axis=2)).mean(axis=2)
    f, P = welch(X, fs=rate_hz, nperseg=min(64, T), detrend="constant", axis=2)
    dfreq = f[1] - f[0]
    tot = P.sum(axis=2)
    centroid = np.where(tot > 0, (P * f).sum(axis=2) / np.where(tot > 0, tot, 1.0), 0.0)
    for j, ch in enumerate(channels):
        for nm, v in (("mean", mean), ("std", std), ("min", X.min(axis=2)), ("max", X.max(axis=2)),
                      ("p10", p10), ("p50", p50), ("p90", p90), ("skew", skew), ("kurtosis", kurt),
                      ("mad_diff", dabs), ("centroid_hz", centroid)):
            cols[f"{ch}__{nm}"] = v[:, j]
        for k, (lo, hi) in enumerate(bands_hz):
            last = k == len(bands_hz) - 1
            sel = (f >= lo) & ((f <= hi) if last else (f < hi))
            if sel.any():
                cols[f"{ch}__bp_{lo:g}_{hi:g}hz"] = np.log10(P[:, j, sel].sum(axis=1) * dfreq + 1e-12)
    if correlations and C > 1:
        z = c / np.where(std > 1e-9, std, np.inf)[..., None]
        R = np.einsum("nit,njt->nij", z, z) / T
        for a in range(C):
            for b in range(a + 1, C):
                cols[f"corr__{channels[a]}__{channels[b]}"] = R[:, a, b]
    pos = {ch: j for j, ch in enumerate(channels)}
    has_i = {"current_left", "current_right"} <= pos.keys()
    has_v = {"speed_left_mps", "speed_right_mps"} <= pos.keys()
    if has_i:
        iL, iR = X[:, pos["current_left"]], X[:, pos["current_right"]]
        cols["current_lr__diff_mean"] = (iL - iR).mean(axis=1)
        cols["current_lr__diff_std"] = (iL - iR).std(axis=1)
        cols["current_lr__sum_mean"] = (iL + iR).mean(axis=1)
        cols["current_lr__sum_std"] = (iL + iR).std(axis=1)
    if has_v:
        vL, vR = X[:, pos["speed_left_mps"]], X[:, pos["speed_right_mps"]]
        v = 0.5 * (vL + vR)
        cols["speed__forward_mean"] = v.mean(axis=1)
        cols["speed_lr__diff_mean"] = (vR - vL).mean(axis=1)
        cols["speed_lr__diff_std"] = (vR - vL).std(axis=1)
        if "imu_wz" in pos:
            wz = X[:, pos["imu_wz"]]
            wkin = (vR - vL) / track_m
            res = wz - wkin
            cols["skid__yaw_residual_mean"] = res.mean(axis=1)
            cols["skid__yaw_residual_std"] = res.std(axis=1)
            cols["skid__yaw_residual_abs"] = np.abs(res).mean(axis=1)
            cols["skid__yaw_ratio"] = np.abs(wz).mean(axis=1) / np.maximum(np.abs(wkin).mean(axis=1), 0.05)
    if has_v:
        # roughness invariants (as on the reference robot, features.sets): the vibration a surface
        # profile excites grows with speed, so the spread per speed and per speed^2 describes the
        # surface rather than the manoeuvre (speed floored at 0.2 m/s; log10 for scale)
        v_floor = np.maximum(np.abs(v.mean(axis=1)), ROUGHNESS_MIN_SPEED_MPS)
        for ch in IMU_CHANNELS:
            if ch not in pos:
                continue
            s_ch, d_ch = std[:, pos[ch]], dabs[:, pos[ch]]  # the per-channel std and mad_diff above
            cols[f"{ch}__log_std_per_speed2"] = np.log10(s_ch / v_floor ** 2 + 1e-9)
            cols[f"{ch}__log_std_per_speed"] = np.log10(s_ch / v_floor + 1e-9)
            cols[f"{ch}__log_mad_diff_per_speed"] = np.log10(d_ch / v_floor + 1e-9)
        if has_i:
            cols["current_total__log_abs_per_speed"] = np.log10(np.abs(iL + iR).mean(axis=1) / v_floor + 1e-6)
    if has_i and has_v:
        vm = np.maximum(np.abs(v.mean(axis=1)), 0.05)
        cols["current_left__per_speed"] = iL.mean(axis=1) / np.maximum(np.abs(vL.mean(axis=1)), 0.05)
        cols["current_right__per_speed"] = iR.mean(axis=1) / np.maximum(np.abs(vR.mean(axis=1)), 0.05)
        cols["current_total__per_speed"] = (iL + iR).mean(axis=1) / vm
        cols["power_left__mean"] = (iL * vL).mean(axis=1)
        cols["power_right__mean"] = (iR * vR).mean(axis=1)
    names = list(cols)
    F = np.stack([cols[k] for k in names], axis=1)
    return np.nan_to_num(F, nan=0.0, posinf=0.0, neginf=0.0), names


class SideChannelFeatures(TransformerMixin, BaseEstimator):
    """Stateless sklearn transformer of :func:`side_channel_features` (safe inside CV).

    Parameters
    ----------
    channel_names : names of the input channels for a plain (n, C, T) array (a ``Windows``
        input brings its own).
    rate_hz : float, sample rate. track_m : float, wheel track B (m).
    correlations : bool, include channel-pair correlations.
    """

    def __init__(self, channel_names: Sequence[str] | None = None, rate_hz: float = 100.0,
                 track_m: float = 0.5708, correlations: bool = True):
        self.channel_names = channel_names
        self.rate_hz = rate_hz
        self.track_m = track_m
        self.correlations = correlations

    def _arr(self, X):
        names = getattr(X, "channels", None)
        if names is not None:
            return np.asarray(X.X, dtype=np.float64), list(names)
        if self.channel_names is None:
            raise ValueError("SideChannelFeatures: X is a plain array; give channel_names")
        return np.asarray(X, dtype=np.float64), list(self.channel_names)

    def fit(self, X, y=None):
        arr, names = self._arr(X)
        if arr.ndim != 3 or arr.shape[1] != len(names):
            raise ValueError(f"SideChannelFeatures: X must be (n, {len(names)}, T), got {arr.shape}")
        _, fn = side_channel_features(arr[:1], names, self.rate_hz, self.track_m, correlations=self.correlations)
        self.channel_names_ = names
        self.feature_names_out_ = np.asarray(fn, dtype=object)
        return self

    def transform(self, X) -> np.ndarray:
        check_is_fitted(self, "feature_names_out_")
        arr, names = self._arr(X)
        if names != self.channel_names_:
            raise ValueError(f"SideChannelFeatures: expected channels {self.channel_names_}, got {names}")
        F, _ = side_channel_features(arr, names, self.rate_hz, self.track_m, correlations=self.correlations)
        return F

    def get_feature_names_out(self, input_features=None) -> np.ndarray:
        check_is_fitted(self, "feature_names_out_")
        return np.asarray(self.feature_names_out_, dtype=object)


# ---------------------------------------------------------------------------------- models
class AuthorsSVM:
    """The BorealTC authors' SVM recipe (their ``utils/models.py``), re-run as a reference.

    Features: the first four statistical moments (mean, std, skew, Pearson kurtosis) of every
    channel; standardised; ``SVC(kernel="poly", degree=4, gamma="auto", C=100)`` inside an
    output-code multiclass wrapper (seed 21). No search (their fixed settings).
    """

    def fit(self, X, y, groups=None):
        from sklearn.multiclass import OutputCodeClassifier
        from sklearn.pipeline import make_pipeline
        from sklearn.preprocessing import StandardScaler
        from sklearn.svm import SVC

        svc = SVC(kernel="poly", degree=4, gamma="auto", C=100, decision_function_shape="ovo", random_state=21)
        self.model_ = make_pipeline(StandardScaler(), OutputCodeClassifier(svc, random_state=21))
        self.model_.fit(self._moments(X), np.asarray(y))
        return self

    @staticmethod
    def _moments(X) -> np.ndarray:
        from scipy import stats

        A = np.asarray(X.X if hasattr(X, "X") else X, dtype=float)
        with warnings.catch_warnings():  # a constant channel has undefined skew/kurtosis
            warnings.simplefilter("ignore", RuntimeWarning)
            F = np.concatenate([A.mean(axis=2), A.std(axis=2), stats.skew(A, axis=2),
                                stats.kurtosis(A, axis=2, fisher=False)], axis=1)
        return np.nan_to_num(F)

    def predict(self, X) -> np.ndarray:
        return self.model_.predict(self._moments(X))


class BoostedTrees(ClassifierMixin, BaseEstimator):
    """Gradient-boosted trees on :class:`SideChannelFeatures` (a second, non-kernel model).

    ``sklearn.ensemble.HistGradientBoostingClassifier`` with balanced class weights and fixed
    settings (no search: ``max_iter`` trees of learning rate ``learning_rate``, otherwise
    sklearn's defaults; chosen before evaluation, not tuned on any fold). Trees need no feature
    scaling and cope with features of any spread, which the RBF kernel does not. Deterministic
    under ``random_state``. ``groups`` is accepted (and unused) so the protocols can call it
    like the other models.
    """

    def __init__(self, features: SideChannelFeatures | None = None, max_iter: int = 300,
                 learning_rate: float = 0.05, random_state: int = 0):
        self.features = features
        self.max_iter = max_iter
        self.learning_rate = learning_rate
        self.random_state = random_state

    def fit(self, X, y, groups=None):
        from sklearn.base import clone
        from sklearn.ensemble import HistGradientBoostingClassifier

        if int(self.max_iter) < 1 or not float(self.learning_rate) > 0:
            raise ValueError("BoostedTrees: max_iter must be >= 1 and learning_rate > 0")
        self.features_ = clone(self.features) if self.features is not None else SideChannelFeatures()
        F = self.features_.fit(X).transform(X)
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
        check_is_fitted(self, "model_")
        return self.model_.predict_proba(self.features_.transform(X))

    def predict(self, X) -> np.ndarray:
        return self.classes_[np.argmax(self.predict_proba(X), axis=1)]


def protocol_models(quick: bool = False, track_m: float = 0.5708, n_jobs: int = 2) -> dict[str, Callable[[], Any]]:
    """Model factories used for the protocols: ``svm``, ``cnn`` and ``authors-svm``.

    * ``svm``: :class:`~terrainml.models.svm.SVMClassifier` on :class:`SideChannelFeatures`;
      C in (3, 10, 30, 100) and gamma in ("scale" = 1/n_features, about 0.004; 0.001; 0.002)
      searched by its inner grouped 3-fold CV (quick: 3 x 2 values), calibrated.
    * ``cnn``: :class:`~terrainml.models.cnn.CNNClassifier` on the raw windows, defaults but
      ``max_epochs`` 40 (quick 20) and ``patience`` 10 (quick 6), seed 0, torch 2 threads.
    * ``hgb``: :class:`BoostedTrees` (gradient-boosted trees, fixed settings; quick: 150 trees).
    * ``authors-svm``: :class:`AuthorsSVM`.
    """
    from terrainml.models.cnn import CNNClassifier
    from terrainml.models.svm import SVMClassifier

    C_grid = (3.0, 10.0, 30.0) if quick else (3.0, 10.0, 30.0, 100.0)
    gamma_grid = ("scale", 0.001) if quick else ("scale", 0.001, 0.002)
    epochs, patience = (20, 6) if quick else (40, 10)

    def svm():
        return SVMClassifier(features=SideChannelFeatures(track_m=track_m), C_grid=C_grid,
                             gamma_grid=gamma_grid, inner_folds=3, random_state=0, n_jobs=n_jobs)

    def cnn():
        return CNNClassifier(max_epochs=epochs, patience=patience, random_state=0, n_threads=2)

    def hgb():
        return BoostedTrees(SideChannelFeatures(track_m=track_m), max_iter=150 if quick else 300)

    return {"svm": svm, "hgb": hgb, "cnn": cnn, "authors-svm": AuthorsSVM}
