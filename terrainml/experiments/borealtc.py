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

import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
import pandas as pd
from scipy import stats
from sklearn.multiclass import OutputCodeClassifier
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import StandardScaler
from sklearn.svm import SVC

from terrainml.evaluation.cv import CVResult, Scoring, average_results, cross_validate
from terrainml.evaluation.folds import chunk_folds, grouped_folds
from terrainml.features.chunks import (SIDE_CHANNELS, ChunkSet, chunk_windows, make_chunks,  # noqa: F401
                                       windows_per_chunk)
from terrainml.features.side_channel import HUSKY_TRACK_M, SideChannelFeatures, track_of
from terrainml.features.windows import Windows
from terrainml.io.ingest import DatasetReport, load_dataset
from terrainml.models.svm import SVMClassifier
from terrainml.models.trees import BoostedTrees
from terrainml.robot import RobotSpec

__all__ = [
    "SIDE_CHANNELS", "ChunkSet", "make_chunks", "windows_per_chunk", "chunk_windows", "robot_track_m",
    "AuthorsSVM", "protocol_models", "MODELS", "PROTOCOL_SEEDS", "ProtocolData",
    "load_protocol_data", "protocol_folds", "run_protocol", "course_runs", "make_course", "course_score",
    "runs_with_imu",
]

#: model names of :func:`protocol_models`
MODELS = ("svm", "hgb", "cnn", "authors-svm")
#: default fold seeds: 21 = the authors' ``RANDOM_STATE`` for (a), 0 for (b)
PROTOCOL_SEEDS = {"a": 21, "b": 0}


def robot_track_m(robot: RobotSpec) -> float:
    """Left-right wheel distance B (m) (:func:`terrainml.features.side_channel.track_of`)."""
    return track_of(robot)


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
        from terrainml.models.cnn import CNNClassifier, CNNConfig  # noqa: PLC0415 - torch, only for the CNN

        return CNNClassifier(CNNConfig(max_epochs=epochs, patience=patience), random_state=0, n_threads=2)

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
    chunks : ChunkSet. report : the reader's DatasetReport (``classes``: names of labels 0..K-1).
    track_m : wheel track B (m) of the robot.
    """

    windows: Windows
    chunks: ChunkSet
    report: DatasetReport
    track_m: float

    @property
    def class_names(self) -> list[str]:
        return list(self.report.classes)


def load_protocol_data(source: str | Path, robot: RobotSpec, chunk_s: float = 5.0, window_s: float = 1.7,
                       max_windows_per_chunk: int = 11) -> ProtocolData:
    """Read a BorealTC folder, cut 5-s chunks and the balanced windows inside them.

    Raises
    ------
    DatasetSpecError or ValueError
        The folder is unusable: no run could be read, or no complete chunk (message names it).
    """
    tables, rep = load_dataset("borealtc", source, robot=robot)
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
            done[m] = cross_validate(factories[m], W, y, groups, folds=folds, progress=tick,
                                     scoring=Scoring(classes, names, name=f"({protocol}) {m}"))
    return {name: done[name] if "+" not in name else
            average_results([done[q] for q in name.split("+")], name=f"({protocol}) {name}")
            for name in models}


# ---------------------------------------------------------------------- a course of held-out runs
IMU_COLUMNS = ("imu_ax_mps2", "imu_ay_mps2", "imu_az_mps2", "imu_yaw_rate_radps", "imu_roll_rate_radps",
               "imu_pitch_rate_radps", "imu_valid")


def runs_by_class(tables: Sequence[pd.DataFrame]) -> dict[int, list[str]]:
    """Run ids of every class (by label code), sorted by id."""
    by: dict[int, list[str]] = {}
    for df in tables:
        by.setdefault(int(df["terrain"].iloc[0]), []).append(str(df["run_id"].iloc[0]))
    return {c: sorted(by[c]) for c in sorted(by)}


def runs_with_imu(tables: Sequence[pd.DataFrame], per_class: int,
                  exclude: Sequence[str] = ()) -> list[pd.DataFrame]:
    """The first ``per_class`` runs (by id) of every class that have an IMU file, the run ids
    ``exclude`` left out; in class order (the training runs of the DDS fault tests on a BorealTC
    run, ``tests/stream/test_ros2_borealtc.py``, and of the real-data fault soak)."""
    by: dict[int, list[pd.DataFrame]] = {}
    for df in sorted(tables, key=lambda d: str(d["run_id"].iloc[0])):
        if str(df["run_id"].iloc[0]) not in exclude and "imu_valid" in df.columns and bool(df["imu_valid"].any()):
            by.setdefault(int(df["terrain"].iloc[0]), []).append(df)
    return [df for c in sorted(by) for df in by[c][:per_class]]


def course_runs(tables: Sequence[pd.DataFrame], k: int = -1) -> list[str]:
    """The held-out runs of a course, in class order: the ``k``-th run (by id) of every class.

    ``k = -1`` (default) is the last run of every class; ``k = 0, 1, ...`` the rotation of
    ``benchmarks/bench_course_sweep.py`` (up to the run count of the smallest class)."""
    return [ids[k] for ids in runs_by_class(tables).values()]


def make_course(tables: Sequence[pd.DataFrame], run_ids: Sequence[str], segment_s: float = 30.0,
                drop_imu: bool = True) -> pd.DataFrame:
    """One run of ``segment_s`` pieces (from the middle) of each run in ``run_ids``, end to end.

    Per-row labels (``terrain``) are kept; the time axis is continuous (each piece shifted to
    follow the previous one by one tick); ``drop_imu`` removes the IMU columns as if the robot
    had none. The metadata of the first run is kept (classes, robot, rate).
    """
    by_id = {str(df["run_id"].iloc[0]): df for df in tables}
    parts, t_next = [], 0.0
    for rid in run_ids:
        df = by_id[rid]
        rate = _table_rate_hz(df)
        n = int(round(segment_s * rate))
        start = max(0, (len(df) - n) // 2)
        part = df.iloc[start:start + n].copy()
        part["t_s"] = part["t_s"].to_numpy() - part["t_s"].iloc[0] + t_next
        t_next = float(part["t_s"].iloc[-1]) + 1.0 / rate
        parts.append(part)
    course = pd.concat(parts, ignore_index=True)
    if drop_imu:
        course = course.drop(columns=[c for c in IMU_COLUMNS if c in course.columns])
    course["run_id"] = "course"
    course.attrs = dict(tables[0].attrs)
    return course


def _table_rate_hz(df: pd.DataFrame) -> float:
    rate = (df.attrs.get("terrainml") or {}).get("rate_hz")
    return float(rate) if rate else float(1.0 / np.median(np.diff(df["t_s"].to_numpy())))


def course_score(course: pd.DataFrame, served: Sequence[dict], class_names: Sequence[str], robot: RobotSpec,
                 settle_s: float = 3.0, moving_mps: float = 0.2) -> dict[str, Any]:
    """Share of moving ticks served the labelled class, excluding ``settle_s`` after each label change.

    ``served``: one DesiredSlip dict per course row (same order). A tick is moving when the mean
    wheel rim speed exceeds ``moving_mps``. Returns the share, counts, per-class shares and the
    number of ``estimator_unhealthy`` ticks.
    """
    t = course["t_s"].to_numpy()
    lab = course["terrain"].to_numpy()
    om = [c for c in course.columns if c.endswith("_omega_radps")]
    speed = np.abs(course[om].to_numpy(dtype=float)).mean(axis=1) * robot.wheel_radius_m
    change_t = t[np.flatnonzero(np.diff(lab) != 0) + 1]
    settled = np.ones(len(t), bool)
    for tc in np.r_[t[0], change_t]:
        settled &= ~((t >= tc) & (t < tc + settle_s))
    got = np.array([m["terrain_name"] for m in served], dtype=object)
    want = np.array([class_names[int(v)] for v in lab], dtype=object)
    use = settled & (speed > moving_mps)
    ok = got == want
    per = {class_names[int(c)]: float(ok[use & (lab == c)].mean()) if (use & (lab == c)).any() else float("nan")
           for c in np.unique(lab)}
    return {"share": float(ok[use].mean()) if use.any() else float("nan"), "n_ticks": int(use.sum()),
            "per_class": per,
            "estimator_unhealthy": int(sum(m["fallback_reason"] == "estimator_unhealthy" for m in served)),
            "fallback_reasons": {r: int(sum(m["fallback_reason"] == r for m in served))
                                 for r in sorted({m["fallback_reason"] for m in served})}}
