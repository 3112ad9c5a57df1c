"""The BorealTC experiment (Clearpath Husky, five terrains): two evaluation protocols, one library.

Both ``terrainml evaluate-protocol`` and ``benchmarks/bench_borealtc.py`` run through
:func:`load_protocol_data` and :func:`run_protocol`.

Protocol (a), *the authors' protocol* (LaRocque et al., IROS 2024, BorealTC ``main.py`` /
``utils/preprocessing.py``), for a like-for-like comparison with their published numbers:

1. every run is cut into non-overlapping **5-s chunks** from its first IMU sample (an incomplete
   tail is dropped; a chunk with any invalid IMU/wheel/current sample is dropped and counted),
   :func:`make_chunks`;
2. the chunks are split by ``StratifiedKFold(5, shuffle=True)`` on the chunk labels, *not*
   grouped by run: chunks of one run fall into training and test folds
   (:func:`terrainml.evaluation.folds.chunk_folds`, seed 21 = the authors' ``RANDOM_STATE``);
3. inside every chunk, **1.7-s windows** are cut (:func:`chunk_windows`). ``homogeneous=True``
   reproduces the authors' class balancing ("homogeneous augmentation"): the smallest class gets
   ``max_windows_per_chunk`` windows per chunk (33 = a 0.1-s stride in the authors' code), every
   other class ``int(max_windows_per_chunk * n_chunks(smallest) / n_chunks(class))`` windows per
   chunk, evenly spaced, so that every class has about the same number of windows (in training
   *and* in test). Accuracy over windows is then close to the balanced accuracy.

Protocol (b), *grouped by run*: the same windows, ``StratifiedGroupKFold(5, shuffle=True)``
with the run id as group (:func:`terrainml.evaluation.folds.grouped_folds`, seed 0), so no run
is in both training and test: the figure a new run on a known terrain can expect.

Hyper-parameters are never tuned on a test fold: :func:`run_protocol` cross-validates with the
groups of the protocol (chunk ids in (a), run ids in (b)), which also go to the model's
``fit``, whose own inner search splits by them (``SVMClassifier`` grid search,
``CNNClassifier`` early stopping). Models: :func:`protocol_models`; ``A+B`` averages the
out-of-fold probabilities of A and B (:func:`terrainml.evaluation.cv.average_results`).

Departures from the authors' pipeline (documented in ``docs/borealtc.md``): our run tables are
resampled to 100 Hz by linear interpolation (the authors keep the 6.5 Hz wheel service as a
separate, nearest-sample stream); runs without an IMU file have no 5-s chunks in either
protocol (the authors' chunking is driven by the IMU stream, so they drop them too).
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
import pandas as pd
from scipy import stats
from sklearn.multiclass import OutputCodeClassifier
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import StandardScaler
from sklearn.svm import SVC

from terrainml.evaluation.cv import CVResult, average_results, cross_validate
from terrainml.evaluation.folds import chunk_folds, grouped_folds
from terrainml.features.side_channel import HUSKY_TRACK_M, SideChannelFeatures
from terrainml.features.windows import Windows
from terrainml.io.borealtc import BorealReport, load_borealtc
from terrainml.models.svm import SVMClassifier
from terrainml.models.trees import BoostedTrees
from terrainml.robot import RobotSpec

__all__ = [
    "SIDE_CHANNELS", "ChunkSet", "make_chunks", "windows_per_chunk", "chunk_windows", "robot_track_m",
    "AuthorsSVM", "protocol_models", "MODELS", "PROTOCOL_SEEDS", "ProtocolData",
    "load_protocol_data", "protocol_folds", "run_protocol",
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
#: model names of :func:`protocol_models`
MODELS = ("svm", "hgb", "cnn", "authors-svm")
#: default fold seeds: 21 = the authors' ``RANDOM_STATE`` for (a), 0 for (b)
PROTOCOL_SEEDS = {"a": 21, "b": 0}


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
    md = tables[0].attrs.get("terrainml") or {}
    rj = md.get("robot_spec") or md.get("robot_json")
    if rj:
        try:
            d = json.loads(rj) if isinstance(rj, str) else rj
            return float(d["wheel_radius_m"])
        except (ValueError, KeyError, TypeError):
            pass
    return 1.0


def robot_track_m(robot: RobotSpec) -> float:
    """Left-right wheel distance B (m): |y| of wheel 1 minus wheel 2 (the Husky's when the robot
    has a single wheel)."""
    wheels = robot.wheels
    return float(abs(wheels[0].y_m - wheels[1].y_m)) if len(wheels) > 1 else HUSKY_TRACK_M


# ---------------------------------------------------------------------------------- models
class AuthorsSVM:
    """The BorealTC authors' SVM recipe (their ``utils/models.py``), re-run as a reference.

    Features: the first four statistical moments (mean, std, skew, Pearson kurtosis) of every
    channel; standardised; ``SVC(kernel="poly", degree=4, gamma="auto", C=100)`` inside an
    output-code multiclass wrapper (seed 21). No search (their fixed settings); labels only
    (no ``predict_proba``).
    """

    def fit(self, X, y, groups=None):
        svc = SVC(kernel="poly", degree=4, gamma="auto", C=100, decision_function_shape="ovo", random_state=21)
        self.model_ = make_pipeline(StandardScaler(), OutputCodeClassifier(svc, random_state=21))
        self.model_.fit(self._moments(X), np.asarray(y))
        return self

    @staticmethod
    def _moments(X) -> np.ndarray:
        A = np.asarray(X.X if hasattr(X, "X") else X, dtype=float)
        with warnings.catch_warnings():  # a constant channel has undefined skew/kurtosis
            warnings.simplefilter("ignore", RuntimeWarning)
            F = np.concatenate([A.mean(axis=2), A.std(axis=2), stats.skew(A, axis=2),
                                stats.kurtosis(A, axis=2, fisher=False)], axis=1)
        return np.nan_to_num(F)

    def predict(self, X) -> np.ndarray:
        return self.model_.predict(self._moments(X))


def protocol_models(quick: bool = False, track_m: float = HUSKY_TRACK_M,
                    n_jobs: int = 2) -> dict[str, Callable[[], Any]]:
    """Model factories used for the protocols: ``svm``, ``hgb``, ``cnn`` and ``authors-svm``.

    * ``svm``: :class:`~terrainml.models.svm.SVMClassifier` on :class:`SideChannelFeatures`;
      C in (3, 10, 30, 100) and gamma in ("scale" = 1/n_features, about 0.004; 0.001; 0.002)
      searched by its inner grouped 3-fold CV (quick: 3 x 2 values), calibrated.
    * ``cnn``: :class:`~terrainml.models.cnn.CNNClassifier` on the raw windows, defaults but
      ``max_epochs`` 40 (quick 20) and ``patience`` 10 (quick 6), seed 0, torch 2 threads.
    * ``hgb``: :class:`~terrainml.models.trees.BoostedTrees` (gradient-boosted trees, fixed
      settings; quick: 150 trees).
    * ``authors-svm``: :class:`AuthorsSVM`.
    """
    C_grid = (3.0, 10.0, 30.0) if quick else (3.0, 10.0, 30.0, 100.0)
    gamma_grid = ("scale", 0.001) if quick else ("scale", 0.001, 0.002)
    epochs, patience = (20, 6) if quick else (40, 10)

    def svm():
        return SVMClassifier(features=SideChannelFeatures(track_m=track_m), C_grid=C_grid,
                             gamma_grid=gamma_grid, inner_folds=3, random_state=0, n_jobs=n_jobs)

    def cnn():
        from terrainml.models.cnn import CNNClassifier  # noqa: PLC0415 - torch, only for the CNN

        return CNNClassifier(max_epochs=epochs, patience=patience, random_state=0, n_threads=2)

    def hgb():
        return BoostedTrees(SideChannelFeatures(track_m=track_m), max_iter=150 if quick else 300)

    return {"svm": svm, "hgb": hgb, "cnn": cnn, "authors-svm": AuthorsSVM}


# ------------------------------------------------------------------------------ protocols
@dataclass
class ProtocolData:
    """The windows both protocols evaluate.

    Attributes
    ----------
    windows : Windows (n, 10, T) with meta ``run_id, terrain, chunk_id, ...``.
    chunks : ChunkSet. report : the reader's BorealReport (``classes``: names of labels 0..K-1).
    track_m : wheel track B (m) of the robot.
    """

    windows: Windows
    chunks: ChunkSet
    report: BorealReport
    track_m: float

    @property
    def class_names(self) -> list[str]:
        return list(self.report.classes)


def load_protocol_data(source: str | Path, robot: RobotSpec, chunk_s: float = 5.0, window_s: float = 1.7,
                       max_windows_per_chunk: int = 11) -> ProtocolData:
    """Read a BorealTC folder, cut 5-s chunks and the balanced windows inside them.

    Raises
    ------
    BorealTCError or ValueError
        The folder is unusable: no run could be read, or no complete chunk (message names it).
    """
    tables, rep = load_borealtc(source, robot=robot)
    if not tables:
        raise ValueError(f"{source}: no run could be read ({rep.skipped})")
    chunks = make_chunks(tables, chunk_s=chunk_s)
    if len(chunks) == 0:
        raise ValueError(f"{source}: no complete {chunk_s:g}-s chunk with valid IMU and wheel data")
    W = chunk_windows(tables, chunks, window_s=window_s, max_windows_per_chunk=max_windows_per_chunk)
    return ProtocolData(W, chunks, rep, robot_track_m(robot))


def protocol_folds(windows: Windows, protocol: str, n_splits: int = 5,
                   seed: int | None = None) -> tuple[list, np.ndarray]:
    """Folds of protocol ``a`` (over chunks) or ``b`` (by run), and the groups they never split.

    ``seed`` None: :data:`PROTOCOL_SEEDS`. Returns (folds, groups (n,)): chunk ids in (a), run
    ids in (b).
    """
    seed = PROTOCOL_SEEDS[protocol] if seed is None else seed
    y = windows.meta["terrain"].to_numpy()
    if protocol == "a":
        groups = windows.meta["chunk_id"].to_numpy()
        return chunk_folds(y, groups, n_splits, seed), groups
    if protocol == "b":
        groups = windows.meta["run_id"].astype(str).to_numpy()
        return grouped_folds(y, groups, n_splits, seed), groups
    raise ValueError(f"unknown protocol {protocol!r}; expected 'a' or 'b'")


def run_protocol(data: ProtocolData, protocol: str, models: Sequence[str], *, n_splits: int = 5,
                 seed: int | None = None, quick: bool = False, n_jobs: int = 2,
                 progress: Callable[[str, int, int], None] | None = None) -> dict[str, CVResult]:
    """Cross-validate models under one protocol.

    Parameters
    ----------
    data : :func:`load_protocol_data` output.
    protocol : ``a`` or ``b`` (see the module docstring). n_splits, seed : its folds.
    models : names of :data:`MODELS`, or ``A+B`` for the mean of their out-of-fold
        probabilities; every base model is evaluated once.
    quick, n_jobs : see :func:`protocol_models` (``n_jobs``: the SVM's inner search).
    progress : callback ``(model, folds done, n folds)``.

    Returns
    -------
    dict model name -> CVResult (named ``"(p) model"``), in the order of ``models``.
    """
    folds, groups = protocol_folds(data.windows, protocol, n_splits, seed)
    W = data.windows
    y = W.meta["terrain"].to_numpy()
    classes = np.unique(y)
    names = [data.class_names[int(c)] for c in classes]
    factories = protocol_models(quick, data.track_m, n_jobs=n_jobs)
    done: dict[str, CVResult] = {}
    for m in dict.fromkeys(q for name in models for q in name.split("+")):
        tick = None if progress is None else (lambda k, n, m=m: progress(m, k, n))
        with warnings.catch_warnings():  # few windows of a class in an inner split: expected
            warnings.simplefilter("ignore", UserWarning)
            done[m] = cross_validate(factories[m], W, y, groups, folds=folds, classes=classes,
                                     class_names=names, name=f"({protocol}) {m}", progress=tick)
    return {name: done[name] if "+" not in name else
            average_results([done[q] for q in name.split("+")], name=f"({protocol}) {name}")
            for name in models}
