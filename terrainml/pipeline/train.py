"""Train, cross-validate, report and save; evaluate a saved model on other data.

:func:`train` runs, for every requested model (``svm``, ``cnn``, ``hgb``, or ``A+B``: the mean of
A's and B's probabilities, :class:`~terrainml.models.ensemble.ProbabilityAverage`), grouped K-fold CV
(:mod:`terrainml.evaluation.cv`, seeded) and a final fit on all windows, measures per-window
latency, runs the SVM feature-set ablation (kinematic / currents / imu / all) on the same folds,
then writes the artifact (:mod:`terrainml.models.artifacts`) with the desired-slip table as an
attachment (:data:`TABLE_FILE`, when the class set is ours) and the report
(:mod:`terrainml.evaluation.report`) into one folder whose manifest hashes every file. The model
with the best CV balanced accuracy is the folder's default (served) model.

Feature families (design §8-9): windows of the canonical channels get
:class:`~terrainml.features.sets.FeatureSet`; windows of a camera-less robot's side channels
(the ``chunks`` spec) get :class:`~terrainml.features.side_channel.SideChannelFeatures` and the
settings of the BorealTC protocols (``experiments/borealtc.py``), so ``train`` and
``evaluate-protocol -p b`` fit the same models. The manifest records the family, the channels
and the sensor groups the model needs (``sensors``).

A class with fewer than :data:`MIN_RUNS_PER_CLASS` runs cannot be tested on a run it was not
trained on: it is named, left out of the cross-validation and of the served replay
(``report.json``: ``excluded_classes``) and kept in the final fit
(:data:`~terrainml.pipeline.preflight.SINGLE_RUN_RULE`).

With a :class:`ServePlan` holding the ingested runs, :func:`train` also proves the served model
on the served path before it saves it: every fold's model (fitted without the fold's runs) is
saved and loaded as ``terrainml predict`` loads it and serves a course of the fold's held-out
runs (:func:`replay_folds`, :mod:`terrainml.pipeline.replay`, the same replay as the selecting
``train``); a model whose replay classifies too little is refused
(:class:`~terrainml.pipeline.replay.ReplayRefused`, report written, no model saved) unless
``allow_unproven``.

:func:`evaluate` loads a verified model folder and scores it on another dataset.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from tempfile import TemporaryDirectory
from typing import Any, Callable, Sequence

import numpy as np
import pandas as pd

from terrainml.classes import TERRAIN_CLASSES
from terrainml.evaluation.cv import average_results, cross_validate
from terrainml.evaluation.folds import grouped_folds
from terrainml.evaluation.metrics import classification_metrics, is_ordered, latency_per_window_ms
from terrainml.evaluation.open_set import OpenSetResult, leave_one_class_out
from terrainml.evaluation.report import write_report
from terrainml.features.sets import FEATURE_SUBSETS, FeatureSet
from terrainml.features.side_channel import SideChannelFeatures, track_of
from terrainml.features.windows import is_side_channel_set
from terrainml.lookup.table import DesiredSlipTable
from terrainml.models.artifacts import (Artifact, ArtifactError, load_artifact, save_artifact,
                                        write_manifest)
from terrainml.models.calibration import Temperature
from terrainml.models.ensemble import ProbabilityAverage
from terrainml.models.novelty import DEFAULT_FALSE_ALARM, NoveltyError, check_false_alarm, fit_model_novelty
from terrainml.models.svm import SVMClassifier
from terrainml.models.trees import BoostedTrees
from terrainml.pipeline.dataset import Dataset
from terrainml.pipeline.progress import report
from terrainml.pipeline.preflight import MIN_RUNS_PER_CLASS, SINGLE_RUN_RULE, table_for_classes
from terrainml.pipeline.replay import (MIN_CLASSIFIED_SHARE, REPLAY_SEGMENT_S, ReplayRefused, make_course,
                                       pooled_replay, replay_course, replay_refusal)

__all__ = ["MODEL_KINDS", "TABLE_FILE", "make_factory", "train", "evaluate", "TrainResult",
           "desired_slip_table_for", "served_table", "parse_models", "feature_family",
           "MIN_RUNS_PER_CLASS", "ClassMismatchError", "parse_class_map", "served_novelty",
           "evaluate_open_set", "ServePlan", "FoldModel", "replay_folds", "class_names_of"]

#: base model kinds; ``A+B`` averages the probabilities of A and B
MODEL_KINDS = ("svm", "cnn", "hgb")
#: SVM search grid of the side-channel family (the BorealTC protocols' ``svm``)
SIDE_C_GRID = (3.0, 10.0, 30.0, 100.0)
SIDE_GAMMA_GRID = ("scale", 0.001, 0.002)
#: the desired-slip table's attachment in a model folder (read back by :func:`served_table`)
TABLE_FILE = "desired_slip_table.json"


def _cnn_class():
    try:
        from terrainml.models.cnn import CNNClassifier  # noqa: PLC0415 - torch, optional
    except ImportError as exc:  # pragma: no cover - cnn.py ships with the package
        raise RuntimeError(f"the CNN model is not available in this install ({exc})") from None
    return CNNClassifier


class ClassMismatchError(ValueError):
    """The data's (or a table's) class names differ from the model's (both sets listed)."""


def parse_models(spec: str | Sequence[str]) -> list[str]:
    """Model names from ``svm``, ``cnn``, ``hgb``, ``all`` (svm and cnn) or ``A+B`` averages.

    ``"svm,svm+hgb"`` -> ``["svm", "svm+hgb"]``. ValueError names an unknown kind.
    """
    items = [m.strip() for m in (spec.split(",") if isinstance(spec, str) else spec) if m.strip()]
    out: list[str] = []
    for m in items:
        names = ["svm", "cnn"] if m == "all" else [m]
        for name in names:
            parts = name.split("+")
            bad = [q for q in parts if q not in MODEL_KINDS]
            if bad or len(set(parts)) != len(parts):
                raise ValueError(f"unknown model {name!r}; expected {', '.join(MODEL_KINDS)}, all, or "
                                 "an average of distinct ones such as svm+hgb")
            if name not in out:
                out.append(name)
    if not out:
        raise ValueError("no model given")
    return out


def feature_family(channels: Sequence[str]) -> str:
    """``side_channel`` for a camera-less robot's side channels, else ``canonical`` (design §8)."""
    return "side_channel" if is_side_channel_set(channels) else "canonical"


def make_factory(kind: str, ds: Dataset, seed: int = 0, subset: str = "all", n_jobs: int | None = 1,
                 params: dict | None = None) -> Callable[[], Any]:
    """Factory of unfitted classifiers on raw windows for a model kind.

    Parameters
    ----------
    kind : ``svm``, ``cnn`` or ``hgb``.
    ds : the dataset (robot constants, channel names).
    seed : random_state of the model.
    subset : SVM feature subset.
    n_jobs : SVM inner-search jobs; the CNN gets ``n_threads=1`` when folds run in parallel.
    params : extra constructor parameters.
    """
    params = dict(params or {})
    side = feature_family(ds.windows.channels) == "side_channel"
    if side:
        sfs = SideChannelFeatures(rate_hz=ds.windows.rate_hz, track_m=track_of(ds.robot))
    if kind == "svm" and side:  # the BorealTC protocols' SVM (experiments.borealtc.protocol_models)
        kw = {"C_grid": SIDE_C_GRID, "gamma_grid": SIDE_GAMMA_GRID, "inner_folds": 3, **params}
        return lambda: SVMClassifier(features=sfs, random_state=seed, n_jobs=n_jobs or 1, **kw)
    if kind == "hgb":
        feats = sfs if side else FeatureSet.for_robot(ds.robot, subset=subset, channel_names=ds.windows.channels,
                                                       rate_hz=ds.windows.rate_hz)
        return lambda: BoostedTrees(feats, random_state=seed, **params)
    if kind == "svm":
        fs = FeatureSet.for_robot(ds.robot, subset=subset, channel_names=ds.windows.channels,
                                  rate_hz=ds.windows.rate_hz)
        return lambda: SVMClassifier(features=fs, random_state=seed, n_jobs=n_jobs, **params)
    if kind == "cnn":
        CNN = _cnn_class()
        return lambda: CNN(channel_names=tuple(ds.windows.channels), random_state=seed, **params)
    raise ValueError(f"unknown model kind {kind!r}; expected one of {MODEL_KINDS}")


def desired_slip_table_for(ds: Dataset | None, robot: Any, catalogue: str | None = None) -> Any:
    """The desired-slip table of the dataset's class set for ``robot`` (design §10), or None.

    ``catalogue`` (``train --catalogue``: a YAML path or built-in name) must have every class
    (ValueError naming it). Without it, our eight classes (design §6.1) get
    :meth:`DesiredSlipTable.build`; a dataset that brings its own class names gets the table of
    the first built-in terrain catalogue that has every one of them (BorealTC's five: the
    ``borealtc`` catalogue), ids in the dataset's order. With no such catalogue the desired-slip
    error is n/a, no table is stored with the model and serving gives every class the class-free
    safe cap (:class:`~terrainml.lookup.table.ClassFreeTargets`).
    """
    all_names = None if ds is None else ds.windows.attrs.get("all_class_names")
    return table_for_classes(robot, list(TERRAIN_CLASSES) if all_names is None else list(all_names), catalogue)[0]


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
    open_set: Any = None
    manifest: dict = field(default_factory=dict)
    fitted: dict = field(default_factory=dict)
    #: the served replay of every fold's held-out runs (``folds``, ``pooled``, ``refusal``, ...) or None
    replay: dict | None = None
    #: the checks before the long work (:meth:`~terrainml.pipeline.preflight.Preflight.doc`) or None
    preflight: dict | None = None


@dataclass
class ServePlan:
    """How :func:`train` proves and equips the model for serving.

    Attributes
    ----------
    tables : the ingested run tables the dataset was cut from (None: no replay, e.g. a windows file).
    segment_s : s of every held-out run replayed. allow_unproven : save a model the replay
        refuses (the report says so). min_classified_share : the refusal threshold.
    catalogue : terrain catalogue of the desired-slip table (``--catalogue``), None: built-in.
    preflight : the report's entry of the checks run before (or None).
    """

    tables: Sequence[pd.DataFrame] | None = None
    segment_s: float = REPLAY_SEGMENT_S
    allow_unproven: bool = False
    min_classified_share: float = MIN_CLASSIFIED_SHARE
    catalogue: str | None = None
    preflight: dict | None = None


@dataclass
class FoldModel:
    """One fold's model, to serve on the fold's held-out runs (:func:`replay_folds`).

    Attributes
    ----------
    runs : the held-out run ids. fitted : {name: fitted model} to save (an average's members too).
    served : the name served. train_windows : the fold's training windows (its novelty score).
    temperature : of the served model's probabilities (1: uncalibrated). label : report label.
    """

    runs: list
    fitted: dict
    served: str
    train_windows: Any
    temperature: float = 1.0
    label: str = ""


def class_names_of(ds: Dataset, classes: Sequence[int]) -> list[str]:
    """Names of the class ids ``classes`` of a dataset (its full name list, else its own)."""
    all_names = ds.windows.attrs.get("all_class_names")
    own = dict(zip(ds.class_ids, ds.class_names))
    return [str(all_names[c]) if all_names is not None and c < len(all_names) else own.get(c, str(c))
            for c in classes]


def replay_folds(folds: Sequence[FoldModel], ds: Dataset, tables: Sequence[pd.DataFrame], table: Any,
                 segment_s: float, seed: int, say: Callable[[str], None],
                 false_alarm: float = DEFAULT_FALSE_ALARM) -> list[dict]:
    """Replay of every fold's held-out runs through its model and its novelty score (fitted on the
    fold's training windows only), saved and loaded as ``terrainml predict`` loads them.

    A fold model is saved with the classes it was fitted on (a class left out of the folds, e.g.
    one with a single run, is neither known to it nor among its held-out runs).

    Returns
    -------
    list of dicts per fold: ``fold``, ``chosen``, ``runs`` and :func:`~terrainml.pipeline.replay.
    replay_course`'s figures, ``replay_s``.
    """
    out = []
    by_id = {str(t["run_id"].iloc[0]): t for t in tables if len(t)}
    for k, f in enumerate(folds):
        runs = [r for r in f.runs if r in by_id]
        report(say, "served replay", k, len(folds), "folds",
               f"fold {k + 1}: {len(runs)} held-out runs through the online predictor")
        if not runs:
            out.append({"fold": k, "runs": 0, "moving_ticks": 0, "chosen": f.label or f.served})
            continue
        model = f.fitted[f.served]
        novelty = served_novelty(model, f.served, f.train_windows, seed, say, false_alarm)
        classes = sorted(int(c) for c in np.asarray(model.classes_).tolist())
        with TemporaryDirectory() as tmp:
            save_artifact(Path(tmp) / "m", f.fitted, classes=classes, class_names=class_names_of(ds, classes),
                          channels=ds.windows.channels, window_spec=ds.spec, robot=ds.robot,
                          training_fingerprint=ds.fingerprint, default_model=f.served, preset=ds.preset,
                          sensors=ds.sensors, feature_family=feature_family(ds.windows.channels),
                          attachments={TABLE_FILE: table.to_json() + "\n"} if table is not None else None,
                          calibration={f.served: Temperature(f.temperature).to_dict()}, novelty=novelty)
            course = make_course([by_id[r] for r in runs], runs, segment_s=segment_s)
            t0 = time.perf_counter()
            res = replay_course(Path(tmp) / "m", course)
        out.append({"fold": k, "chosen": f.label or f.served, "runs": len(runs), **res,
                    "replay_s": time.perf_counter() - t0})
    report(say, "served replay", len(folds), len(folds), "folds")
    return out


def _ablation(ds: Dataset, folds, seed: int, n_jobs: int, table, classes, cv_all=None,
              params: dict | None = None, windows=None) -> pd.DataFrame:
    W = ds.windows if windows is None else windows
    rows = []
    for subset in FEATURE_SUBSETS:
        try:
            n_feat = FeatureSet.for_robot(ds.robot, subset=subset).fit(ds.windows.subset([0])).n_features_out_
        except ValueError:
            continue  # e.g. imu subset on a robot without IMU channels
        if subset == "all" and cv_all is not None:
            res = cv_all
        else:
            res = cross_validate(make_factory("svm", ds, seed, subset, params=params), W, W.y,
                                 W.groups, folds=folds, n_jobs=n_jobs, table=table, classes=classes)
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
          progress: Callable[[str], None] | None = None, open_set: bool = False,
          novelty_false_alarm: float = DEFAULT_FALSE_ALARM, serve: ServePlan | None = None) -> TrainResult:
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
    progress : callback with a short message per stage and a
        :class:`~terrainml.pipeline.progress.Step` per fit (stages ``cross-validation``,
        ``final fit``, ``ablation``, ``open set``).
    open_set : also run the leave-one-class-out evaluation of the served model's novelty score
        on the same folds (:mod:`terrainml.evaluation.open_set`; one more CV per class).
    novelty_false_alarm : the novelty threshold's target, the share of moving known windows of a
        held-out training run over it (default 0.05; higher finds more unknown ground and serves
        more known ground the safe cap: docs/models.md "Unknown ground").
    serve : :class:`ServePlan`: the runs to replay every fold's held-out runs from (served path,
        refusal), the terrain catalogue, the checks' report entry. None: no replay, built-in tables.

    The served model's novelty score (:mod:`terrainml.models.novelty`, threshold from inner
    grouped folds of the training windows) is fitted and saved with it when the model has a
    feature space (svm, hgb or an average with one of them).

    Returns
    -------
    TrainResult (its ``manifest`` is the written manifest). Raises
    :class:`~terrainml.pipeline.replay.ReplayRefused` (after writing the report, no model saved)
    when the served replay refuses the model and ``serve.allow_unproven`` is False.
    """
    say = progress or (lambda msg: None)
    out = Path(out)
    models = parse_models(models)
    check_false_alarm(novelty_false_alarm)
    serve = serve or ServePlan()
    plan = _cv_plan(ds, folds, seed, say)
    W = plan.W
    table = desired_slip_table_for(ds, ds.robot, serve.catalogue)
    bases = list(dict.fromkeys(q for m in models for q in m.split("+")))
    results, fitted, factories = _fit_bases(ds, bases, plan, table, seed, n_jobs, model_params, say,
                                            keep_folds=serve.tables is not None)
    for name in models:
        if "+" in name:
            members = name.split("+")
            results[name] = {"cv": average_results([results[q]["cv"] for q in members], name=name, table=table),
                             "fit_time_s": sum(results[q]["fit_time_s"] for q in members),
                             "params": {"members": members}}
            fitted[name] = ProbabilityAverage.from_fitted([fitted[q] for q in members])
    for name, model in fitted.items():
        results[name]["latency"] = latency_per_window_ms(model, W, n_calls=min(200, max(20, len(W))))
    # report and save the requested models (an average's members are stored for it anyway)
    results = {k: results[k] for k in [*models, *[b for b in bases if b not in models]]}
    fitted = {k: fitted[k] for k in results}
    abl = None
    if ablation and "svm" in models and feature_family(W.channels) == "canonical":
        report(say, "ablation", 0, None, "", "svm feature sets")
        abl = _ablation(ds, plan.folds, seed, n_jobs, table, plan.cv_classes, results["svm"]["cv"],
                        (model_params or {}).get("svm"), windows=plan.Wcv)
    order = list(results)
    default = max((k for k in results if k in models),
                  key=lambda k: (results[k]["cv"].summary["balanced_accuracy"]["mean"], -order.index(k)))
    summary = _dataset_summary(ds, plan)
    res = TrainResult(out, results, default, plan.classes.tolist(), plan.names, len(plan.folds), seed, summary,
                      abl, fitted=fitted, preflight=serve.preflight)
    if serve.tables is not None:
        res.replay = _served_replay(ds, plan, default, results, table, serve, seed, say, novelty_false_alarm)
        if res.replay["refusal"] and not serve.allow_unproven:
            write_report(out, res)
            raise ReplayRefused(f"{res.replay['refusal']}; not saved; override with --allow-unproven", out)
    novelty = served_novelty(fitted[default], default, W, seed, say, novelty_false_alarm)
    if open_set and novelty is not None:
        report(say, "open set", 0, None, "", f"each class of {default} held out in turn")
        res.open_set = _open_set(default, factories, plan, seed, n_jobs, say, novelty_false_alarm)
    metrics_summary = {k: r["cv"].summary for k, r in results.items()}
    save_artifact(out, fitted, classes=plan.classes.tolist(), class_names=plan.names, channels=W.channels,
                  window_spec=ds.spec, robot=ds.robot, training_fingerprint=ds.fingerprint,
                  metrics_summary=metrics_summary, default_model=default, preset=ds.preset,
                  sensors=ds.sensors, feature_family=feature_family(W.channels), novelty=novelty,
                  attachments={TABLE_FILE: table.to_json() + "\n"} if table is not None else None,
                  extra={"folds": len(plan.folds), "seed": seed, "n_windows": len(W),
                         "latency_ms": {k: r["latency"] for k, r in results.items()},
                         "excluded_classes": summary["excluded_classes"]})
    write_report(out, res)
    res.manifest = write_manifest(out)  # hash the report files too
    return res


@dataclass
class _CVPlan:
    """What :func:`train` cross-validates on: the classes, the runs per class, the folds.

    ``W`` all windows (the final fit); ``Wcv`` the windows of the classes with at least
    :data:`MIN_RUNS_PER_CLASS` runs (``cv_classes``), split into grouped ``folds``.
    """

    W: Any
    classes: np.ndarray
    names: list
    name_of: dict
    runs_per_class: dict
    excluded: list
    cv_classes: np.ndarray
    Wcv: Any
    folds: list
    cv_names: list


def _cv_plan(ds: Dataset, folds: int, seed: int, say: Callable[[str], None]) -> _CVPlan:
    """Classes, runs per class and grouped folds; classes with a single run leave the CV (named)."""
    W = ds.windows
    if len(W) == 0:
        raise ValueError("the dataset has no windows (see the rejection counts of `dataset build`)")
    y, groups = W.y, W.groups
    classes = np.asarray(sorted(set(y.tolist())))
    if len(classes) < 2:
        raise ValueError(f"need at least 2 classes to train, the dataset has {classes.tolist()}")
    names = list(ds.class_names) if ds.class_names else [str(c) for c in classes]
    name_of = dict(zip(classes.tolist(), names))
    # classes with a single run: never tested on an unseen run under grouped CV -> out of the CV
    runs_per_class = {int(c): len(set(groups[y == c])) for c in classes}
    excluded = [int(c) for c in classes if runs_per_class[int(c)] < MIN_RUNS_PER_CLASS]
    cv_classes = np.asarray([c for c in classes if int(c) not in excluded])
    if len(cv_classes) < 2:
        raise ValueError(f"grouped CV needs at least 2 classes with >= {MIN_RUNS_PER_CLASS} runs; runs per "
                         f"class: { {name_of[c]: n for c, n in runs_per_class.items()} }; record more runs")
    for c in excluded:
        say(f"warning: class {name_of[c]!r} has {runs_per_class[c]} run(s): {SINGLE_RUN_RULE}; record "
            "another run of it to score it")
    keep = np.isin(y, cv_classes)
    Wcv = W.subset(np.flatnonzero(keep)) if not keep.all() else W
    fold_list = grouped_folds(Wcv.y, Wcv.groups, folds, seed)
    return _CVPlan(W, classes, names, name_of, runs_per_class, excluded, cv_classes, Wcv, fold_list,
                   [name_of[int(c)] for c in cv_classes])


def _fit_bases(ds: Dataset, bases: list[str], plan: _CVPlan, table, seed: int, n_jobs: int,
               model_params: dict | None, say: Callable[[str], None],
               keep_folds: bool = False) -> tuple[dict, dict, dict]:
    """Cross-validate and fit every base model kind on all windows: (results, fitted, factories) by kind;
    ``keep_folds``: the CV results keep their fold models (the served replay serves them)."""
    W, Wcv = plan.W, plan.Wcv
    results: dict[str, dict] = {}
    fitted: dict[str, Any] = {}
    factories: dict[str, Callable[[], Any]] = {}
    for kind in bases:
        params = (model_params or {}).get(kind, {})
        inner_jobs = 1 if n_jobs != 1 else None
        if kind == "cnn" and n_jobs != 1:
            params = {"n_threads": 1, **params}
        factory = make_factory(kind, ds, seed, n_jobs=inner_jobs, params=params)
        factories[kind] = factory
        n_cv, before = len(bases) * len(plan.folds), len(results) * len(plan.folds)
        report(say, "cross-validation", before, n_cv, "fits", f"{kind}: grouped {len(plan.folds)}-fold CV")
        cv = cross_validate(factory, Wcv, Wcv.y, Wcv.groups, folds=plan.folds, n_jobs=n_jobs, table=table,
                            classes=plan.cv_classes, class_names=plan.cv_names, name=kind, keep_models=keep_folds,
                            progress=lambda i, n: report(say, "cross-validation", before + i, n_cv, "fits", kind))
        report(say, "final fit", len(results), len(bases), "models", f"{kind} on {len(W)} windows")
        model = factory()
        t0 = time.perf_counter()
        model.fit(W, W.y, groups=W.groups)
        fit_s = time.perf_counter() - t0
        p = dict(getattr(model, "best_params_", {}) or {})
        if kind == "cnn":
            p = {"best_epoch": getattr(model, "best_epoch_", None), "n_epochs": getattr(model, "n_epochs_", None)}
        results[kind] = {"cv": cv, "fit_time_s": fit_s, "params": p}
        fitted[kind] = model
        report(say, "final fit", len(results), len(bases), "models", kind)
    return results, fitted, factories


def _served_replay(ds: Dataset, plan: _CVPlan, default: str, results: dict, table: Any, serve: ServePlan,
                   seed: int, say: Callable[[str], None], false_alarm: float) -> dict:
    """The served model's fold models replayed on their folds' held-out runs (:func:`replay_folds`):
    the report's ``replay`` entry (per fold, pooled, the refusal or "")."""
    Wcv = plan.Wcv
    groups = np.asarray(Wcv.groups).astype(str)
    parts = default.split("+")
    folds = []
    for k, (tr, te) in enumerate(plan.folds):
        fold_models = [results[q]["cv"].fold_models[k] for q in parts]
        fitted = dict(zip(parts, fold_models))
        if len(parts) > 1:
            fitted[default] = ProbabilityAverage.from_fitted(fold_models)
        folds.append(FoldModel(sorted(set(groups[te].tolist())), fitted, default, Wcv.subset(tr)))
    per_fold = replay_folds(folds, ds, serve.tables, table, serve.segment_s, seed, say, false_alarm)
    pooled = pooled_replay([f for f in per_fold if f.get("moving_ticks")])
    refusal = replay_refusal(pooled, serve.min_classified_share)
    return {"folds": per_fold, "pooled": pooled, "refusal": refusal,
            "overridden": bool(refusal and serve.allow_unproven), "segment_s": serve.segment_s,
            "min_classified_share": serve.min_classified_share}


def _dataset_summary(ds: Dataset, plan: _CVPlan) -> dict:
    """The report's dataset summary: runs, windows and runs per class, excluded classes, provenance."""
    W = plan.W
    y, groups = W.y, W.groups
    name_of, runs_per_class = plan.name_of, plan.runs_per_class
    return {"n_runs": int(len(np.unique(groups))), "n_windows": int(len(W)),
            "windows_per_class": {str(n): int((y == c).sum()) for c, n in zip(plan.classes, plan.names)},
            "runs_per_class": {name_of[c]: n for c, n in runs_per_class.items()},
            "excluded_classes": [{"class": name_of[c], "runs": runs_per_class[c],
                                  "reason": f"fewer than {MIN_RUNS_PER_CLASS} runs: {SINGLE_RUN_RULE}"}
                                 for c in plan.excluded],
            "feature_family": feature_family(W.channels), "sensors": ds.sensors,
            "window_spec": ds.spec.name,
            "robot": ds.robot.name, "preset": ds.preset, "channels": list(W.channels),
            "fingerprint": ds.fingerprint, "rejections": ds.counts}


def served_novelty(model: Any, name: str, W, seed: int, say: Callable[[str], None],
                   false_alarm: float = DEFAULT_FALSE_ALARM):
    """(name, scorer, info) of the served model's novelty score, or None (named) without one;
    ``false_alarm``: the threshold's target (:func:`~terrainml.models.novelty.fit_novelty`)."""
    say(f"{name}: novelty score (threshold at {100 * false_alarm:g} % of the training runs' moving windows, "
        "one run held out at a time)")
    try:
        scorer, info = fit_model_novelty(model, W, seed=seed, false_alarm=false_alarm)
    except NoveltyError as exc:
        say(f"{name}: no novelty score ({exc})")
        return None
    return name, scorer, info


def _open_set(default: str, factories: dict, plan: _CVPlan, seed: int, n_jobs: int,
              say: Callable[[str], None], false_alarm: float = DEFAULT_FALSE_ALARM):
    """Leave-one-class-out evaluation of the served model's novelty on the CV folds."""
    members = [factories[q] for q in default.split("+")]
    factory = members[0] if len(members) == 1 else (lambda: ProbabilityAverage([f() for f in members]))
    return leave_one_class_out(factory, plan.Wcv, folds=plan.folds, classes=plan.cv_classes.tolist(),
                               class_names=plan.cv_names, seed=seed, n_jobs=n_jobs, progress=say,
                               false_alarm=false_alarm)


def evaluate_open_set(ds: Dataset, model: str = "svm", folds: int = 5, seed: int = 0, n_jobs: int = 1,
                      progress: Callable[[str], None] | None = None,
                      false_alarm: float = DEFAULT_FALSE_ALARM) -> OpenSetResult:
    """Leave-one-class-out evaluation of a model kind's novelty score on a window dataset.

    The same classes, grouped folds and factories as :func:`train` (``_cv_plan``,
    :func:`make_factory`); each CV class in turn is held out of training and plays the unknown
    (:func:`~terrainml.evaluation.open_set.leave_one_class_out`). ``model``: ``svm``, ``hgb``
    or an average such as ``svm+hgb`` (a model with a feature space; not ``cnn``).
    ``false_alarm``: the threshold's target, as :func:`train`'s ``novelty_false_alarm``.

    Raises ValueError naming the model for a kind without a feature space or several models,
    and (from the plan) for a dataset with fewer than 3 classes that have 2 runs or more.
    """
    say = progress or (lambda msg: None)
    kinds = parse_models(model)
    if len(kinds) != 1:
        raise ValueError(f"open-set evaluation takes one model, got {kinds}")
    name = kinds[0]
    if "cnn" in name.split("+"):
        raise ValueError(f"model {name!r}: the CNN has no feature space for the novelty score; use svm or hgb")
    plan = _cv_plan(ds, folds, seed, say)
    if len(plan.cv_classes) < 3:
        raise ValueError(f"open-set evaluation needs at least 3 classes with >= {MIN_RUNS_PER_CLASS} runs "
                         f"(one held out, two known); the dataset has {plan.cv_names}")
    inner_jobs = 1 if n_jobs != 1 else None
    factories = {q: make_factory(q, ds, seed, n_jobs=inner_jobs) for q in name.split("+")}
    return _open_set(name, factories, plan, seed, n_jobs, say, false_alarm)


def parse_class_map(text: str | None) -> dict[str, str]:
    """``"A=B,C=D"`` -> ``{"A": "B", "C": "D"}`` (data class name -> model class name)."""
    out: dict[str, str] = {}
    for item in (text or "").split(","):
        if not item.strip():
            continue
        if item.count("=") != 1 or not all(p.strip() for p in item.split("=")):
            raise ValueError(f"--class-map: {item!r} is not DATA_CLASS=MODEL_CLASS")
        a, b = (p.strip() for p in item.split("="))
        out[a] = b
    return out


def match_classes(data_names: Sequence[str], model_names: Sequence[str],
                  class_map: dict[str, str] | None = None, source: str = "the data") -> dict[str, str]:
    """Data class name -> model class name, matched by name (never by id).

    Every data class must be one of the model's (after ``class_map``); otherwise
    :class:`ClassMismatchError` lists both sets and the names that differ.
    """
    class_map = dict(class_map or {})
    unknown_keys = sorted(set(class_map) - set(data_names))
    if unknown_keys:
        raise ClassMismatchError(f"--class-map names {unknown_keys}, which {source} does not have "
                                 f"(its classes: {sorted(data_names)})")
    mapping = {n: class_map.get(n, n) for n in data_names}
    missing = sorted({n for n, m in mapping.items() if m not in set(model_names)})
    if missing:
        raise ClassMismatchError(
            f"class names differ: {source} has {sorted(data_names)}, the model has {sorted(model_names)}; "
            f"not in the model: {missing}. Map them with --class-map DATA=MODEL,... if they are the "
            "same terrain under another name")
    return mapping


def evaluate(model_dir: str | Path, ds: Dataset, model: str | None = None,
             class_map: dict[str, str] | None = None, **load_kwargs: Any) -> dict:
    """Score a saved model (verified on load) on a dataset, classes matched by name.

    ``class_map`` maps data class names to model class names (``--class-map A=B``); a data class
    the model lacks is refused (:class:`ClassMismatchError`, both sets listed). ``load_kwargs`` go
    to :func:`~terrainml.models.artifacts.load_artifact` (e.g. ``trusted_keys``).

    Returns
    -------
    dict with ``balanced_accuracy, accuracy, macro_f1, desired_slip_error_mean, n_windows``, the
    other metrics of :func:`classification_metrics`, ``model``, ``model_dir``,
    ``training_fingerprint`` and ``data_fingerprint``.
    """
    art = load_artifact(model_dir, model, **load_kwargs)
    W = ds.windows
    model_names = list(art.class_names) or [str(c) for c in art.class_ids]
    data_ids = sorted(set(W.y.tolist()))
    all_names = W.attrs.get("all_class_names")
    if all_names is not None:
        data_name = {i: str(all_names[i]) if 0 <= i < len(all_names) else str(i) for i in data_ids}
    else:
        data_name = {i: n for i, n in zip(ds.class_ids, ds.class_names)}
        data_name = {i: data_name.get(i, TERRAIN_CLASSES[i] if 0 <= i < len(TERRAIN_CLASSES) else str(i))
                     for i in data_ids}
    mapping = match_classes([data_name[i] for i in data_ids], model_names, class_map)
    model_id = dict(zip(model_names, art.class_ids))
    relabel = {i: int(model_id[mapping[data_name[i]]]) for i in data_ids}
    missing = [c for c in art.channels if c not in W.channels]
    if missing:
        raise ValueError(f"the data lacks channels {missing} the model {art.model_name!r} was trained on")
    W = W.select_channels(art.channels)
    if len(W) == 0:
        raise ValueError("the evaluation data has no windows")
    proba = np.asarray(art.model.predict_proba(W), dtype=float)
    classes = np.asarray(art.model.classes_)
    y_pred = classes[np.argmax(proba, axis=1)]
    y_true = np.asarray([relabel[int(v)] for v in W.y], dtype=np.int64)
    m = classification_metrics(y_true, y_pred, proba, classes, served_table(art),
                               ordered=is_ordered(art.class_names or None))
    m.update({"model": art.model_name, "model_kind": art.kind, "model_dir": str(model_dir),
              "training_fingerprint": art.manifest.get("training_fingerprint"),
              "data_fingerprint": ds.fingerprint,
              "class_names": art.class_names,
              "class_map": {k: v for k, v in mapping.items() if k != v}})
    return m
