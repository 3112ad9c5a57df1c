"""Train, cross-validate, report and save; evaluate a saved model on other data.

:func:`train` runs, for every requested model kind (``svm``, ``cnn``), grouped K-fold CV
(:mod:`terrainml.evaluation.cv`, seeded) and a final fit on all windows, measures per-window
latency, runs the SVM feature-set ablation (kinematic / currents / imu / all) on the same folds,
then writes the artifact (:mod:`terrainml.models.artifacts`) with the desired-slip table as an
attachment (:data:`TABLE_FILE`, when the class set is ours) and the report
(:mod:`terrainml.evaluation.report`) into one folder whose manifest hashes every file. The model
with the best CV balanced accuracy is the folder's default (served) model.

:func:`evaluate` loads a verified model folder and scores it on another dataset.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
import pandas as pd

from terrainml.classes import TERRAIN_CLASSES
from terrainml.evaluation.cv import cross_validate
from terrainml.evaluation.folds import grouped_folds
from terrainml.evaluation.metrics import classification_metrics, latency_per_window_ms
from terrainml.evaluation.report import write_report
from terrainml.features.sets import FEATURE_SUBSETS, FeatureSet
from terrainml.lookup.table import DesiredSlipTable
from terrainml.models.artifacts import (Artifact, ArtifactError, load_artifact, save_artifact,
                                        write_manifest)
from terrainml.models.svm import SVMClassifier
from terrainml.pipeline.dataset import Dataset

__all__ = ["MODEL_KINDS", "TABLE_FILE", "make_factory", "train", "evaluate", "TrainResult",
           "desired_slip_table_for", "served_table"]

MODEL_KINDS = ("svm", "cnn")
#: the desired-slip table's attachment in a model folder (read back by :func:`served_table`)
TABLE_FILE = "desired_slip_table.json"


def _cnn_class():
    try:
        from terrainml.models.cnn import CNNClassifier  # noqa: PLC0415 - torch, optional
    except ImportError as exc:  # pragma: no cover - cnn.py ships with the package
        raise RuntimeError(f"the CNN model is not available in this install ({exc})") from None
    return CNNClassifier


def make_factory(kind: str, ds: Dataset, seed: int = 0, subset: str = "all", n_jobs: int | None = 1,
                 params: dict | None = None) -> Callable[[], Any]:
    """Factory of unfitted classifiers on raw windows for a model kind.

    Parameters
    ----------
    kind : ``svm`` or ``cnn``.
    ds : the dataset (robot constants, channel names).
    seed : random_state of the model.
    subset : SVM feature subset.
    n_jobs : SVM inner-search jobs; the CNN gets ``n_threads=1`` when folds run in parallel.
    params : extra constructor parameters.
    """
    params = dict(params or {})
    if kind == "svm":
        fs = FeatureSet.for_robot(ds.robot, subset=subset, channel_names=ds.windows.channels,
                                  rate_hz=ds.windows.rate_hz)
        return lambda: SVMClassifier(features=fs, random_state=seed, n_jobs=n_jobs, **params)
    if kind == "cnn":
        CNN = _cnn_class()
        return lambda: CNN(channel_names=tuple(ds.windows.channels), random_state=seed, **params)
    raise ValueError(f"unknown model kind {kind!r}; expected one of {MODEL_KINDS}")


def desired_slip_table_for(ds: Dataset | None, robot: Any) -> Any:
    """The desired-slip table when the class set is ours (SYSTEM §6.1), else None.

    A dataset that brings its own class names (e.g. BorealTC) has no desired-slip targets: the
    desired-slip error is then reported as n/a and no table is stored with the model.
    """
    all_names = None if ds is None else ds.windows.attrs.get("all_class_names")
    if all_names is not None and list(all_names) != list(TERRAIN_CLASSES):
        return None
    try:
        return DesiredSlipTable.build(robot)
    except Exception:  # noqa: BLE001 - the metric is then reported as n/a
        return None


def served_table(art: Artifact) -> DesiredSlipTable | None:
    """The desired-slip table stored with a verified model folder, or None when it has none.

    Raises ArtifactError (naming the file) when the stored table is not a valid table of the
    folder's robot.
    """
    path = art.attachments.get(TABLE_FILE)
    if path is None:
        return None
    try:
        return DesiredSlipTable.from_json(path.read_text(), robot=art.robot, source=str(path))
    except ValueError as exc:
        raise ArtifactError(str(exc)) from None


@dataclass
class TrainResult:
    """What :func:`train` produced (also the input of the report)."""

    out: Path
    models: dict
    default_model: str
    class_ids: list
    class_names: list
    n_folds: int
    seed: int
    dataset_summary: dict
    ablation: pd.DataFrame | None = None
    manifest: dict = field(default_factory=dict)
    fitted: dict = field(default_factory=dict)


def _ablation(ds: Dataset, folds, seed: int, n_jobs: int, table, classes, cv_all=None,
              params: dict | None = None) -> pd.DataFrame:
    rows = []
    for subset in FEATURE_SUBSETS:
        try:
            n_feat = FeatureSet.for_robot(ds.robot, subset=subset).fit(ds.windows.subset([0])).n_features_out_
        except ValueError:
            continue  # e.g. imu subset on a robot without IMU channels
        if subset == "all" and cv_all is not None:
            res = cv_all
        else:
            res = cross_validate(make_factory("svm", ds, seed, subset, params=params), ds.windows, ds.windows.y,
                                 ds.windows.groups, folds=folds, n_jobs=n_jobs, table=table, classes=classes)
        s = res.summary
        get = lambda k, q: s.get(k, {}).get(q, float("nan"))  # noqa: E731
        rows.append({"subset": subset, "n_features": n_feat,
                     "balanced_accuracy_mean": get("balanced_accuracy", "mean"),
                     "balanced_accuracy_std": get("balanced_accuracy", "std"),
                     "macro_f1_mean": get("macro_f1", "mean"), "macro_f1_std": get("macro_f1", "std"),
                     "desired_slip_error_mean": get("desired_slip_error_mean", "mean")})
    return pd.DataFrame(rows)


def train(ds: Dataset, out: str | Path, models: Sequence[str] = ("svm",), folds: int = 5, seed: int = 0,
          n_jobs: int = 1, ablation: bool = True, model_params: dict | None = None,
          progress: Callable[[str], None] | None = None) -> TrainResult:
    """Cross-validate, fit, report and save models on a window dataset.

    Parameters
    ----------
    ds : Dataset (from :func:`terrainml.pipeline.dataset.build_dataset` or ``read_windows``).
    out : model folder (``runs/NAME``), created.
    models : model kinds among ``svm``, ``cnn``.
    folds : outer grouped folds. seed : seed of folds and models.
    n_jobs : joblib jobs over folds.
    ablation : run the SVM feature-set ablation.
    model_params : {kind: {param: value}} constructor overrides.
    progress : callback with a short message per stage.

    Returns
    -------
    TrainResult (its ``manifest`` is the written manifest).
    """
    say = progress or (lambda msg: None)
    out = Path(out)
    W = ds.windows
    if len(W) == 0:
        raise ValueError("the dataset has no windows (see the rejection counts of `dataset build`)")
    y, groups = W.y, W.groups
    classes = np.asarray(sorted(set(y.tolist())))
    if len(classes) < 2:
        raise ValueError(f"need at least 2 classes to train, the dataset has {classes.tolist()}")
    for kind in models:
        if kind not in MODEL_KINDS:
            raise ValueError(f"unknown model kind {kind!r}; expected one of {MODEL_KINDS}")
    table = desired_slip_table_for(ds, ds.robot)
    fold_list = grouped_folds(y, groups, folds, seed)
    results: dict[str, dict] = {}
    fitted: dict[str, Any] = {}
    for kind in models:
        params = (model_params or {}).get(kind, {})
        inner_jobs = 1 if n_jobs != 1 else None
        if kind == "cnn" and n_jobs != 1:
            params = {"n_threads": 1, **params}
        factory = make_factory(kind, ds, seed, n_jobs=inner_jobs, params=params)
        say(f"{kind}: grouped {len(fold_list)}-fold cross-validation")
        cv = cross_validate(factory, W, y, groups, folds=fold_list, n_jobs=n_jobs, table=table, classes=classes)
        say(f"{kind}: final fit on {len(W)} windows")
        model = factory()
        t0 = time.perf_counter()
        model.fit(W, y, groups=groups)
        fit_s = time.perf_counter() - t0
        lat = latency_per_window_ms(model, W, n_calls=min(200, max(20, len(W))))
        p = dict(getattr(model, "best_params_", {}) or {})
        if kind == "cnn":
            p = {"best_epoch": getattr(model, "best_epoch_", None), "n_epochs": getattr(model, "n_epochs_", None)}
        results[kind] = {"cv": cv, "latency": lat, "fit_time_s": fit_s, "params": p}
        fitted[kind] = model
    abl = None
    if ablation and "svm" in models:
        say("svm: feature-set ablation")
        abl = _ablation(ds, fold_list, seed, n_jobs, table, classes, results["svm"]["cv"],
                        (model_params or {}).get("svm"))
    default = max(results, key=lambda k: (results[k]["cv"].summary["balanced_accuracy"]["mean"],
                                          -MODEL_KINDS.index(k)))
    names = list(ds.class_names) if ds.class_names else [str(c) for c in classes]
    summary = {"n_runs": int(len(np.unique(groups))), "n_windows": int(len(W)),
               "windows_per_class": {str(n): int((y == c).sum()) for c, n in zip(classes, names)},
               "robot": ds.robot.name, "preset": ds.preset, "channels": list(W.channels),
               "fingerprint": ds.fingerprint, "rejections": ds.counts}
    res = TrainResult(out, results, default, classes.tolist(), names, len(fold_list), seed, summary, abl,
                      fitted=fitted)
    metrics_summary = {k: r["cv"].summary for k, r in results.items()}
    save_artifact(out, fitted, classes=classes.tolist(), class_names=names, channels=W.channels,
                  window_spec=ds.spec, robot=ds.robot, training_fingerprint=ds.fingerprint,
                  metrics_summary=metrics_summary, default_model=default, preset=ds.preset,
                  attachments={TABLE_FILE: table.to_json() + "\n"} if table is not None else None,
                  extra={"folds": len(fold_list), "seed": seed, "n_windows": len(W),
                         "latency_ms": {k: r["latency"] for k, r in results.items()}})
    write_report(out, res)
    res.manifest = write_manifest(out)  # hash the report files too
    return res


def evaluate(model_dir: str | Path, ds: Dataset, model: str | None = None) -> dict:
    """Score a saved model (verified on load) on a dataset.

    Returns
    -------
    dict with ``balanced_accuracy, accuracy, macro_f1, desired_slip_error_mean, n_windows``, the
    other metrics of :func:`classification_metrics`, ``model``, ``model_dir``,
    ``training_fingerprint`` and ``data_fingerprint``.
    """
    art = load_artifact(model_dir, model)
    W = ds.windows
    missing = [c for c in art.channels if c not in W.channels]
    if missing:
        raise ValueError(f"the data lacks channels {missing} the model {art.model_name!r} was trained on")
    W = W.select_channels(art.channels)
    if len(W) == 0:
        raise ValueError("the evaluation data has no windows")
    proba = np.asarray(art.model.predict_proba(W), dtype=float)
    classes = np.asarray(art.model.classes_)
    y_pred = classes[np.argmax(proba, axis=1)]
    m = classification_metrics(W.y, y_pred, proba, classes, served_table(art))
    m.update({"model": art.model_name, "model_kind": art.kind, "model_dir": str(model_dir),
              "training_fingerprint": art.manifest.get("training_fingerprint"),
              "data_fingerprint": ds.fingerprint,
              "class_names": art.class_names})
    return m
