"""Train, cross-validate, report and save; evaluate a saved model on other data.

:func:`train` runs, for every requested model (``svm``, ``cnn``, ``hgb``, or ``A+B``: the mean of
A's and B's probabilities, :class:`~terrainml.models.ensemble.ProbabilityAverage`), grouped K-fold CV
(:mod:`terrainml.evaluation.cv`, seeded) and a final fit on all windows, measures per-window
latency, runs the SVM feature-set ablation (kinematic / currents / imu / all) on the same folds,
then writes the artifact (:mod:`terrainml.models.artifacts`) with the desired-slip table as an
attachment (:data:`~terrainml.models.artifacts.TABLE_FILE`, when the class set is ours) and the report
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

Given the ingested runs (``tables``), :func:`train` also proves the served model
on the served path before it saves it: every fold's model (fitted without the fold's runs) is
saved and loaded as ``terrainml predict`` loads it and serves a course of the fold's held-out
runs (:func:`~terrainml.pipeline.fold_replay.replay_folds`, the same replay as the selecting
``train``; with the sensor members its held-out runs call on when the folder gets members,
:func:`fold_model`); a model whose replay classifies too little is refused
(:class:`~terrainml.pipeline.replay.ReplayRefused`, report written, no model saved) unless
``allow_unproven`` (:class:`~terrainml.pipeline.train_options.ReplayOptions`). The options come as
frozen records resolved once by the command line (:mod:`terrainml.pipeline.train_options`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np
import pandas as pd

from terrainml.classes import TERRAIN_CLASSES
from terrainml.evaluation.cv import Scoring, average_results, cross_validate
from terrainml.evaluation.folds import grouped_folds
from terrainml.evaluation.metrics import latency_per_window_ms
from terrainml.evaluation.open_set import NoveltySettings, OpenSetResult, leave_one_class_out
from terrainml.evaluation.report import write_report
from terrainml.features.sets import FEATURE_SUBSETS, FeatureSet
from terrainml.features.side_channel import SideChannelFeatures, track_of
from terrainml.features.windows import is_side_channel_set
from terrainml.lookup.table import DesiredSlipTable
from terrainml.models.artifacts import (TABLE_FILE, Artifact, ArtifactError, TrainingProvenance, save_artifact,
                                        write_manifest)
from terrainml.models.ensemble import ProbabilityAverage
from terrainml.models.svm import SVMClassifier
from terrainml.models.trees import BoostedTrees
from terrainml.pipeline.candidates import MODEL_KINDS, parse_models
from terrainml.pipeline.dataset import Dataset
from terrainml.pipeline.fold_replay import FoldModel, FoldMember, replay_folds, served_novelty, table_attachment
from terrainml.pipeline.train_options import ReplayOptions, TrainOptions
from terrainml.pipeline.progress import report
from terrainml.pipeline.preflight import MIN_RUNS_PER_CLASS, SINGLE_RUN_RULE, table_for_classes
from terrainml.pipeline.replay import ReplayRefused, make_course, pooled_replay, replay_refusal
from terrainml.pipeline.sensor_subsets import MEMBER_DROPS, flagged_groups, member_subsets, subset_dataset

__all__ = ["make_factory", "train", "TrainResult", "desired_slip_table_for", "served_table",
           "feature_family", "MIN_RUNS_PER_CLASS", "evaluate_open_set", "fold_model", "class_names_of",
           "provenance_of", "dataset_summary"]

#: SVM search grid of the side-channel family (the BorealTC protocols' ``svm``)
SIDE_C_GRID = (3.0, 10.0, 30.0, 100.0)
SIDE_GAMMA_GRID = ("scale", 0.001, 0.002)


def _cnn_class():
    try:
        from terrainml.models.cnn import CNNClassifier  # noqa: PLC0415 - torch, optional
    except ImportError as exc:  # pragma: no cover - cnn.py ships with the package
        raise RuntimeError(f"the CNN model is not available in this install ({exc})") from None
    return CNNClassifier


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
        return lambda: CNN.from_params(channel_names=tuple(ds.windows.channels), random_state=seed, **params)
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


def class_names_of(ds: Dataset, classes: Sequence[int]) -> list[str]:
    """Names of the class ids ``classes`` of a dataset (its full name list, else its own)."""
    all_names = ds.windows.attrs.get("all_class_names")
    own = dict(zip(ds.class_ids, ds.class_names))
    return [str(all_names[c]) if all_names is not None and c < len(all_names) else own.get(c, str(c))
            for c in classes]


def provenance_of(ds: Dataset, classes: Sequence[int],
                  class_names: Sequence[str] | None = None) -> TrainingProvenance:
    """The provenance saved with models fitted on ``ds``'s windows of ``classes`` (named
    ``class_names``, default :func:`class_names_of`)."""
    W = ds.windows
    names = class_names_of(ds, classes) if class_names is None else list(class_names)
    return TrainingProvenance(classes=list(classes), class_names=names, channels=W.channels, window_spec=ds.spec,
                              robot=ds.robot, training_fingerprint=ds.fingerprint, preset=ds.preset,
                              sensors=ds.sensors, feature_family=feature_family(W.channels))


def _ablation(ds: Dataset, plan: _CVPlan, opt: TrainOptions, table: Any, cv_all: Any) -> pd.DataFrame:
    """The SVM feature-set ablation on the CV folds: one row per feature subset the robot feeds
    (``cv_all``: the CV of the ``all`` subset, already run)."""
    W = plan.Wcv
    params = opt.model_params.get("svm")
    rows = []
    for subset in FEATURE_SUBSETS:
        try:
            n_feat = FeatureSet.for_robot(ds.robot, subset=subset).fit(ds.windows.subset([0])).n_features_out_
        except ValueError:
            continue  # e.g. imu subset on a robot without IMU channels
        if subset == "all" and cv_all is not None:
            res = cv_all
        else:
            res = cross_validate(make_factory("svm", ds, opt.seed, subset, params=params), W, W.y,
                                 W.groups, folds=plan.folds, n_jobs=opt.n_jobs,
                                 scoring=Scoring(plan.cv_classes, table=table))
        s = res.summary
        get = lambda k, q: s.get(k, {}).get(q, float("nan"))  # noqa: E731
        rows.append({"subset": subset, "n_features": n_feat,
                     "balanced_accuracy_mean": get("balanced_accuracy", "mean"),
                     "balanced_accuracy_std": get("balanced_accuracy", "std"),
                     "macro_f1_mean": get("macro_f1", "mean"), "macro_f1_std": get("macro_f1", "std"),
                     "desired_slip_error_mean": get("desired_slip_error_mean", "mean")})
    return pd.DataFrame(rows)


def train(ds: Dataset, out: str | Path, models: Sequence[str] = ("svm",), options: TrainOptions | None = None,
          serve: ReplayOptions | None = None, *, tables: Sequence[pd.DataFrame] | None = None,
          preflight: dict | None = None, progress: Callable[[str], None] | None = None) -> TrainResult:
    """Cross-validate, fit, report and save models on a window dataset.

    Parameters
    ----------
    ds : Dataset (from :func:`terrainml.pipeline.dataset.build_dataset` or ``read_windows``).
    out : model folder (``runs/NAME``), created.
    models : model kinds among ``svm``, ``cnn``, ``hgb`` or averages ``A+B``.
    options : :class:`~terrainml.pipeline.train_options.TrainOptions` (folds, seed, jobs, ablation,
        open set, novelty target, model parameters); None: the defaults.
    serve : :class:`~terrainml.pipeline.train_options.ReplayOptions` (replay length, refusal, terrain
        catalogue); None: the defaults.
    tables : the ingested run tables the dataset was cut from: every fold's held-out runs are
        replayed through the served path (refusal). None: no replay (e.g. a windows file).
    preflight : the report's entry of the checks run before (or None).
    progress : callback with a short message per stage and a
        :class:`~terrainml.pipeline.progress.Step` per fit (stages ``cross-validation``,
        ``final fit``, ``ablation``, ``open set``).

    The served model's novelty score (:mod:`terrainml.models.novelty`, threshold from inner
    grouped folds of the training windows at ``options.novelty_false_alarm``) is fitted and saved
    with it when the model has a feature space (svm, hgb or an average with one of them). With
    ``options.open_set`` the leave-one-class-out evaluation of that score runs on the same folds
    (:mod:`terrainml.evaluation.open_set`; one more CV per class).

    Returns
    -------
    TrainResult (its ``manifest`` is the written manifest). Raises
    :class:`~terrainml.pipeline.replay.ReplayRefused` (after writing the report, no model saved)
    when the served replay refuses the model and ``serve.allow_unproven`` is False.
    """
    say = progress or (lambda msg: None)
    out = Path(out)
    models = parse_models(models)
    opt = options or TrainOptions()
    serve = serve or ReplayOptions()
    seed = opt.seed
    plan = _cv_plan(ds, opt.folds, seed, say)
    W = plan.W
    table = desired_slip_table_for(ds, ds.robot, serve.catalogue)
    bases = list(dict.fromkeys(q for m in models for q in m.split("+")))
    results, fitted, factories = _fit_bases(ds, bases, plan, table, opt, say, keep_folds=tables is not None)
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
    if opt.ablation and "svm" in models and feature_family(W.channels) == "canonical":
        report(say, "ablation", 0, None, "", "svm feature sets")
        abl = _ablation(ds, plan, opt, table, results["svm"]["cv"])
    order = list(results)
    default = max((k for k in results if k in models),
                  key=lambda k: (results[k]["cv"].summary["balanced_accuracy"]["mean"], -order.index(k)))
    summary = dataset_summary(ds, plan.name_of, plan.runs_per_class, plan.excluded)
    res = TrainResult(out, results, default, plan.classes.tolist(), plan.names, len(plan.folds), seed, summary,
                      abl, fitted=fitted, preflight=preflight)
    if tables is not None:
        res.replay = _served_replay(ds, plan, default, results, table, tables, serve, opt, say)
        if res.replay["refusal"] and not serve.allow_unproven:
            write_report(out, res)
            raise ReplayRefused(f"{res.replay['refusal']}; not saved; override with --allow-unproven", out)
    novelty = served_novelty(fitted[default], default, W, seed, say, opt.novelty_false_alarm)
    if opt.open_set and novelty is not None:
        report(say, "open set", 0, None, "", f"each class of {default} held out in turn")
        res.open_set = _open_set(default, factories, plan, opt, say)
    metrics_summary = {k: r["cv"].summary for k, r in results.items()}
    save_artifact(out, fitted, provenance_of(ds, plan.classes.tolist(), plan.names),
                  metrics_summary=metrics_summary, default_model=default, novelty=novelty,
                  attachments=table_attachment(table),
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


def _fit_bases(ds: Dataset, bases: list[str], plan: _CVPlan, table: Any, opt: TrainOptions,
               say: Callable[[str], None], keep_folds: bool = False) -> tuple[dict, dict, dict]:
    """Cross-validate and fit every base model kind on all windows: (results, fitted, factories) by kind;
    ``keep_folds``: the CV results keep their fold models (the served replay serves them)."""
    W, Wcv = plan.W, plan.Wcv
    results: dict[str, dict] = {}
    fitted: dict[str, Any] = {}
    factories: dict[str, Callable[[], Any]] = {}
    seed, n_jobs = opt.seed, opt.n_jobs
    for kind in bases:
        params = dict(opt.model_params.get(kind, {}))
        inner_jobs = 1 if n_jobs != 1 else None
        if kind == "cnn" and n_jobs != 1:
            params = {"n_threads": 1, **params}
        factory = make_factory(kind, ds, seed, n_jobs=inner_jobs, params=params)
        factories[kind] = factory
        n_cv, before = len(bases) * len(plan.folds), len(results) * len(plan.folds)
        report(say, "cross-validation", before, n_cv, "fits", f"{kind}: grouped {len(plan.folds)}-fold CV")
        cv = cross_validate(factory, Wcv, Wcv.y, Wcv.groups, folds=plan.folds, n_jobs=n_jobs, keep_models=keep_folds,
                            scoring=Scoring(plan.cv_classes, plan.cv_names, table, kind),
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


def _served_replay(ds: Dataset, plan: _CVPlan, default: str, results: dict, table: Any,
                   tables: Sequence[pd.DataFrame], serve: ReplayOptions, opt: TrainOptions,
                   say: Callable[[str], None]) -> dict:
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
        folds.append(fold_model(ds, sorted(set(groups[te].tolist())), fitted, default, Wcv.subset(tr), tables,
                                serve, opt.seed))
    per_fold = replay_folds(folds, table, opt.seed, say, opt.novelty_false_alarm, n_jobs=opt.n_jobs)
    pooled = pooled_replay([f for f in per_fold if f.get("moving_ticks")])
    refusal = replay_refusal(pooled, serve.min_classified_share)
    return {"folds": per_fold, "pooled": pooled, "refusal": refusal,
            "overridden": bool(refusal and serve.allow_unproven), "segment_s": serve.segment_s,
            "min_classified_share": serve.min_classified_share}


def fold_model(ds: Dataset, runs: Sequence[str], fitted: dict, served: str, train_windows: Any,
               tables: Sequence[pd.DataFrame], serve: ReplayOptions, seed: int, temperature: float = 1.0,
               label: str = "") -> FoldModel:
    """One fold's model for :func:`~terrainml.pipeline.fold_replay.replay_folds`: fitted on
    ``train_windows`` (windows of ``ds``), held out ``runs``, saved with the provenance of ``ds``'s
    windows of its classes, its course the ``serve.segment_s`` pieces of its held-out runs.

    With ``serve.members`` (the saved folder is served with sensor members) the fold gets each
    member of a model on ``ds``'s groups (:func:`~terrainml.pipeline.sensor_subsets.member_subsets`)
    whose dropped group its course flags invalid
    (:func:`~terrainml.pipeline.sensor_subsets.flagged_groups`): the fold's served model kinds on
    the fold's training windows with the member's channels (``train`` fits a saved member on
    windows cut again for its groups where that gives more; a fold member does with the fold's).
    """
    classes = sorted(int(c) for c in np.asarray(fitted[served].classes_).tolist())
    f = FoldModel(list(runs), fitted, served, train_windows, provenance_of(ds, classes), temperature, label)
    by_id = {str(t["run_id"].iloc[0]): t for t in tables if len(t)}
    f.replayed = [r for r in f.runs if r in by_id]
    if f.replayed:
        f.course = make_course([by_id[r] for r in f.replayed], f.replayed, segment_s=serve.segment_s)
    flagged = flagged_groups([f.course]) if serve.members and f.course is not None else set()
    fold_ds = replace(ds, windows=train_windows)
    for name, subset in member_subsets(ds.sensors).items():
        if MEMBER_DROPS[name] in flagged:
            sub = subset_dataset(fold_ds, subset)
            f.members.append(FoldMember(name, {q: make_factory(q, sub, seed) for q in served.split("+")}, served,
                                        sub.windows, provenance_of(sub, classes)))
    return f


def dataset_summary(ds: Dataset, name_of: Mapping[int, str], runs_per_class: Mapping[int, int],
                    excluded: Sequence[int]) -> dict:
    """The report's dataset summary: runs, windows per class (of ``name_of``, class id -> name, in
    class order), runs per class, the ``excluded`` classes (fewer than :data:`MIN_RUNS_PER_CLASS`
    runs) and the windows' provenance."""
    W = ds.windows
    name = lambda c: name_of.get(int(c), str(c))  # noqa: E731
    return {"n_runs": int(len(np.unique(W.groups))), "n_windows": int(len(W)),
            "windows_per_class": {str(n): int((W.y == c).sum()) for c, n in name_of.items()},
            "runs_per_class": {name(c): int(n) for c, n in runs_per_class.items()},
            "excluded_classes": [{"class": name(c), "runs": int(runs_per_class[c]),
                                  "reason": f"fewer than {MIN_RUNS_PER_CLASS} runs: {SINGLE_RUN_RULE}"}
                                 for c in excluded],
            "feature_family": feature_family(W.channels), "sensors": ds.sensors, "window_spec": ds.spec.name,
            "robot": ds.robot.name, "preset": ds.preset, "channels": list(W.channels),
            "fingerprint": ds.fingerprint, "rejections": ds.counts}


def _open_set(default: str, factories: dict, plan: _CVPlan, opt: TrainOptions, say: Callable[[str], None]):
    """Leave-one-class-out evaluation of the served model's novelty on the CV folds."""
    members = [factories[q] for q in default.split("+")]
    factory = members[0] if len(members) == 1 else (lambda: ProbabilityAverage([f() for f in members]))
    return leave_one_class_out(factory, plan.Wcv, folds=plan.folds, classes=plan.cv_classes.tolist(),
                               class_names=plan.cv_names, seed=opt.seed, n_jobs=opt.n_jobs, progress=say,
                               novelty=NoveltySettings(novelty_false_alarm=opt.novelty_false_alarm))


def evaluate_open_set(ds: Dataset, model: str = "svm", options: TrainOptions | None = None,
                      progress: Callable[[str], None] | None = None) -> OpenSetResult:
    """Leave-one-class-out evaluation of a model kind's novelty score on a window dataset.

    The same classes, grouped folds and factories as :func:`train` (``_cv_plan``,
    :func:`make_factory`); each CV class in turn is held out of training and plays the unknown
    (:func:`~terrainml.evaluation.open_set.leave_one_class_out`). ``model``: ``svm``, ``hgb``
    or an average such as ``svm+hgb`` (a model with a feature space; not ``cnn``). ``options``:
    folds, seed, jobs and the novelty threshold's target, as :func:`train`'s (None: defaults).

    Raises ValueError naming the model for a kind without a feature space or several models,
    and (from the plan) for a dataset with fewer than 3 classes that have 2 runs or more.
    """
    say = progress or (lambda msg: None)
    opt = options or TrainOptions()
    kinds = parse_models(model)
    if len(kinds) != 1:
        raise ValueError(f"open-set evaluation takes one model, got {kinds}")
    name = kinds[0]
    if "cnn" in name.split("+"):
        raise ValueError(f"model {name!r}: the CNN has no feature space for the novelty score; use svm or hgb")
    plan = _cv_plan(ds, opt.folds, opt.seed, say)
    if len(plan.cv_classes) < 3:
        raise ValueError(f"open-set evaluation needs at least 3 classes with >= {MIN_RUNS_PER_CLASS} runs "
                         f"(one held out, two known); the dataset has {plan.cv_names}")
    inner_jobs = 1 if opt.n_jobs != 1 else None
    factories = {q: make_factory(q, ds, opt.seed, n_jobs=inner_jobs) for q in name.split("+")}
    return _open_set(name, factories, plan, opt, say)
