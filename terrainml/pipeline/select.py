"""Nested run-grouped selection of the window spec and the model on the user's own data.

``terrainml train`` with ``--windows auto`` and ``--model auto`` (the defaults) does not trust
settings chosen on the simulator: it scores every *candidate* (a window spec that the data can
feed x a model: ``svm``, ``hgb``, their average ``svm+hgb``; the CNN when asked) on the user's
runs and keeps the best, and it says how good that choice is on runs the choosing never saw.

Folds. The runs are split once into K groups (:func:`~terrainml.evaluation.folds.run_partition`,
stratified by class, weighted by run length), the same runs for every spec. A *level* is a set
``H`` of groups; a candidate's score at ``H`` is the mean over ``d`` in ``H`` of the balanced
accuracy on the windows of group ``d`` of a model fitted on the groups ``H - {d}``.

* Top level ``H`` = all K groups: the ordinary grouped K-fold CV of every candidate (its
  figures in ``report.md``); the best one is the saved model.
* Level ``k`` (``H`` = all groups but ``k``): the same choice made without group ``k``. Its
  winner, fitted on the K - 1 groups, is scored on group ``k``: the *outer* figure. The mean
  over k is the honest figure of the whole procedure (nested CV): choosing is never scored on
  its own test runs. A model fitted on ``K - 2`` groups serves two levels (it is tested on each
  of the two groups it left out for the level of the other), so nested CV costs K (K - 1) / 2
  inner fits per candidate, not K (K - 1).

Screening. At every level, each spec is first scored with a cheap screening model (boosted
trees of :data:`SCREEN_TREES` trees at learning rate :data:`SCREEN_LEARNING_RATE` on the spec's
features, computed once per spec); the candidate models are fitted only for the specs within
:data:`SCREEN_MARGIN` of that level's best spec (a level decides from its own scores, so
screening is as honest as the choice). A spec whose
windows miss a class, or keep fewer than :data:`MIN_WINDOWS_PER_CLASS` of one, is not a
candidate (the reason is reported).

Work shared across fits. Each spec's features are computed once (:meth:`_Fits.features`: the
feature transformers are stateless) and every fold's ``svm`` and ``hgb`` is fitted and scored on
rows of them (:class:`_OnFeatures`, the models' ``fit_features``); the screening model reads the
same features. The SVM's C/gamma search shares one kernel matrix per inner split and gamma
across every C (:func:`terrainml.models.svm._kernel_search`).

A single candidate fixed beforehand (a sensor member of a chosen model, ``nested=False``) gets
its grouped K-fold CV only: nothing is chosen, so that is its honest figure.

Calibration (:mod:`terrainml.models.calibration`). At level ``k`` the winner's out-of-fold
probabilities (its inner predictions: never group ``k``) fit a temperature, applied to its
outer predictions on group ``k``: the ECE before and after on runs the calibration never saw.
The saved model's temperature is fitted on the top level's out-of-fold probabilities. A
temperature is kept only where it lowers the ECE on runs it was not fitted on
(:func:`fit_temperature`: fitted without each run group of the level in turn, scored on that
group); else it stays 1. Measured on the simulator (BENCHMARKS "`train` with no options"): on
windows classified at 0.998 a temperature fitted by likelihood on the few confident errors of
some runs (2.23 in one outer fold) softened the right answers of the others, ECE 0.027 -> 0.149.

The honest figure is given two ways: the mean ± std of the outer folds' balanced accuracies, and
the balanced accuracy *pooled* over every outer fold's held-out windows. The pooled one is the
definition of the evaluation engine (:attr:`terrainml.evaluation.cv.CVResult.balanced_accuracy`,
``train --windows X``'s report and the BorealTC protocol (b)), so it compares with those figures
and with each candidate's pooled CV figure; the mean over folds weighs a small fold like a large
one.

Scores of different specs are over different windows of the same runs (a ``steady`` spec keeps
only cruising windows); the served replay of :mod:`terrainml.pipeline.replay` compares them on
every tick.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Sequence

import numpy as np
from sklearn.base import BaseEstimator, ClassifierMixin, clone
from sklearn.metrics import balanced_accuracy_score
from sklearn.preprocessing import FunctionTransformer

from terrainml.evaluation.cv import assemble_result, predict_held_out
from terrainml.evaluation.folds import folds_of_partition, run_partition
from terrainml.evaluation.metrics import expected_calibration_error
from terrainml.models.calibration import Temperature
from terrainml.models.ensemble import ProbabilityAverage
from terrainml.models.trees import BoostedTrees
from terrainml.pipeline.dataset import Dataset
from terrainml.pipeline.progress import ProgressFn, report
from terrainml.pipeline import train as train_lib  # make_factory read at call time
from terrainml.pipeline.candidates import AUTO_MODELS, parse_auto_models
from terrainml.pipeline.train import MIN_RUNS_PER_CLASS

__all__ = ["Candidate", "Level", "Selection", "select", "SCREEN_TREES", "SCREEN_MARGIN", "MIN_WINDOWS_PER_CLASS",
           "spec_feasibility", "fit_temperature"]

#: the screening model: boosted trees this small on features computed once per spec
SCREEN_TREES = 40
SCREEN_LEARNING_RATE = 0.25
SCREEN = "screen"
#: the other models are fitted for the specs within this much balanced accuracy of the best
SCREEN_MARGIN = 0.03
#: a spec keeping fewer windows of a class (or that class in fewer runs than
#: :data:`~terrainml.pipeline.train.MIN_RUNS_PER_CLASS`) is not a candidate
MIN_WINDOWS_PER_CLASS = 30


@dataclass(frozen=True)
class Candidate:
    """A window spec and a model (``svm``, ``hgb``, ``cnn`` or an average ``A+B``)."""

    spec: str
    model: str

    @property
    def name(self) -> str:
        return f"{self.spec}/{self.model}"

    @property
    def bases(self) -> tuple[str, ...]:
        return tuple(self.model.split("+"))


@dataclass
class Level:
    """The choice made at one level (a set of run groups).

    Attributes
    ----------
    held : run-group indices of the level. scores : candidate name -> mean balanced accuracy
    over the level's held-out groups. per_group : name -> {group: balanced accuracy}.
    screened : spec -> why its models were not fitted at this level. screen_scores : spec ->
    the screening model's score. chosen : name.
    """

    held: tuple[int, ...]
    scores: dict = field(default_factory=dict)
    per_group: dict = field(default_factory=dict)
    screened: dict = field(default_factory=dict)
    screen_scores: dict = field(default_factory=dict)
    chosen: str = ""


@dataclass
class Selection:
    """What :func:`select` measured (the input of the report and of the saved model).

    Attributes
    ----------
    candidates : every candidate of a feasible spec, in order. infeasible : spec -> reason.
    partition : K arrays of run ids. top : the top-level Level (the saved model's choice).
    inner : K Levels, level k without group k. outer : per outer fold k a dict (``chosen``,
    ``balanced_accuracy``, ``ece_before``, ``ece_after``, ``temperature``, ``n_windows``,
    ``runs``). honest : {mean, std} of the outer folds' balanced accuracies and ``pooled``, the
    balanced accuracy over all outer folds' held-out windows together. cv : candidate name ->
    CVResult of the top level (the report's side-by-side figures; screened-out ones absent).
    chosen : Candidate. temperature : float, of the saved model. class_ids / class_names : of
    the CV. timing_s : seconds per stage. budget_note : what the time budget skipped ("" none).
    outer_models : per outer fold k, the level-k winner fitted without group k (uncalibrated;
    its temperature is ``outer[k]["temperature"]``), for the served replay. nested : False when a
    single fixed candidate was scored by its grouped CV alone (``select(nested=False)``).
    """

    candidates: list
    infeasible: dict
    partition: list
    top: Level
    inner: list
    outer: list
    honest: dict
    cv: dict
    chosen: Candidate
    temperature: float
    class_ids: list
    class_names: list
    timing_s: dict = field(default_factory=dict)
    budget_note: str = ""
    outer_models: list = field(default_factory=list)
    nested: bool = True


def spec_feasibility(ds: Dataset, cv_classes: Sequence[int], names: Mapping[int, str]) -> str:
    """"" when the spec's windows can be a candidate, else why not (class, windows, runs named)."""
    W = ds.windows
    for c in cv_classes:
        m = W.y == c
        n, runs = int(m.sum()), len(set(W.groups[m].tolist()))
        if n < MIN_WINDOWS_PER_CLASS or runs < MIN_RUNS_PER_CLASS:
            return (f"keeps {n} window(s) of {names[c]} in {runs} run(s) (needs >= {MIN_WINDOWS_PER_CLASS} "
                    f"in >= {MIN_RUNS_PER_CLASS} runs)")
    return ""


def _bal_acc(y, p, classes) -> float:
    with warnings.catch_warnings():  # a prediction of a class this group lacks
        warnings.simplefilter("ignore")
        return float(balanced_accuracy_score(y, classes[np.argmax(p, axis=1)]))


class _OnFeatures(ClassifierMixin, BaseEstimator):
    """A model of raw windows (``svm``, ``hgb``) fitted and scored on rows of its windows' features
    computed once (:meth:`fit_features`); ``model_`` is the fitted model, which predicts on raw
    windows like one fitted on them."""

    def __init__(self, model: Any = None, features: Any = None):
        self.model = model
        self.features = features

    def fit(self, F, y, groups=None):
        self.model_ = clone(self.model).fit_features(F, y, groups, self.features)
        self.classes_ = self.model_.classes_
        self.best_params_ = dict(getattr(self.model_, "best_params_", {}) or {})
        return self

    def predict_proba(self, F) -> np.ndarray:
        mask = getattr(self.model_, "feature_mask_", None)  # the SVM's selected features
        return self.model_.predict_proba_from_features(F if mask is None else F[:, mask])


class _Fits:
    """Held-out probabilities of (spec, base model, training groups), fitted once each."""

    def __init__(self, data: Mapping[str, Dataset], partition: list, classes: np.ndarray, seed: int,
                 n_jobs: int, progress: ProgressFn):
        self.data = dict(data)
        self.partition = partition
        self.classes = classes
        self.seed = seed
        self.n_jobs = n_jobs
        self.say = progress
        self.gidx = {}
        for s, ds in self.data.items():
            g = np.full(len(ds.windows), -1, dtype=np.int64)
            for k, runs in enumerate(partition):
                g[np.isin(ds.windows.groups, runs)] = k
            self.gidx[s] = g
        self.proba: dict[tuple, np.ndarray] = {}
        self.info: dict[tuple, dict] = {}
        self.models: dict[tuple, Any] = {}  # fitted on K - 1 groups: the outer folds' models
        self._features: dict[tuple, tuple] = {}  # (spec, feature family) -> (transformer, F)
        self.n_fits = 0
        self.fit_s = 0.0
        self.done = 0  # keys settled (fitted, or skipped: a training part with one class)
        self.total = 0  # keys planned (see plan)

    def plan(self, keys: Sequence[tuple]) -> None:
        """Plan the fits ``keys`` still need: the progress total is the keys settled so far plus
        the missing ones (called again when screening or the outer folds change the plan)."""
        total = self.done + len([k for k in dict.fromkeys(keys) if k not in self.proba])
        if total != self.total or self.done == 0:  # the first plan starts the stage
            self.total = total
            report(self.say, "selection", self.done, self.total, "fits")

    def _settled(self, key: tuple) -> None:
        self.done += 1
        self.total = max(self.total, self.done)
        report(self.say, "selection", self.done, self.total, "fits", f"{key[0]}/{key[1]}")

    def ensure(self, keys: Sequence[tuple]) -> None:
        """Fit every missing (spec, base, frozenset of training groups)."""
        todo = [k for k in dict.fromkeys(keys) if k not in self.proba]
        by_model: dict[tuple, list] = {}
        for k in todo:
            by_model.setdefault(k[:2], []).append(k)
        for (spec, base), ks in by_model.items():
            ds = self.data[spec]
            W, g = ds.windows, self.gidx[spec]
            splits, use = [], []
            for k in ks:
                tr = np.flatnonzero(np.isin(g, sorted(k[2])))
                te = np.flatnonzero((g >= 0) & ~np.isin(g, sorted(k[2])))
                if len(np.unique(W.y[tr])) < 2 or len(te) == 0:
                    self.proba[k] = np.full((len(W), len(self.classes)), np.nan)
                    self._settled(k)
                    continue
                splits.append((tr, te))
                use.append(k)
            if not splits:
                continue
            t0 = time.perf_counter()
            X, factory = self._inputs(spec, base)
            keep = [base != SCREEN and len(k[2]) == len(self.partition) - 1 for k in use]
            res = predict_held_out(factory, X, W.y, W.groups, splits, self.classes, n_jobs=self.n_jobs, keep=keep,
                                   progress=lambda i, n: self._settled(use[i - 1]))
            self.fit_s += time.perf_counter() - t0
            for k, (_, te), r in zip(use, splits, res):
                if r["model"] is not None:
                    self.models[k] = r["model"].model_ if isinstance(r["model"], _OnFeatures) else r["model"]
                P = np.full((len(W), len(self.classes)), np.nan)
                P[te] = r["proba"]
                self.proba[k] = P
                self.info[k] = {key: r[key] for key in ("fit_time_s", "predict_time_s", "best_params")}
            self.n_fits += len(splits)

    def _inputs(self, spec: str, base: str) -> tuple[Any, Callable[[], Any]]:
        """(X, factory) of a base model's fits: for a model on window features (``svm``, ``hgb``),
        the spec's features (computed once, shared by every fold and every model of the same
        feature family) and the model fitted on their rows (:class:`_OnFeatures`); else raw
        windows and the model's factory. The screening model: small trees on the trees' features."""
        ds = self.data[spec]
        seed = self.seed
        if base == SCREEN:
            _, F = self.features(spec, "hgb")
            return F, lambda: BoostedTrees(FunctionTransformer(), max_iter=SCREEN_TREES,
                                           learning_rate=SCREEN_LEARNING_RATE, random_state=seed)
        factory = train_lib.make_factory(base, ds, seed, n_jobs=1 if self.n_jobs != 1 else None)
        if not hasattr(factory(), "fit_features"):
            return ds.windows, factory
        feats, F = self.features(spec, base)
        return F, lambda: _OnFeatures(factory(), feats)

    def features(self, spec: str, base: str) -> tuple[Any, np.ndarray]:
        """(fitted transformer, features of every window of ``spec``) of model ``base``'s feature
        family, computed once (the transformers are stateless: a window's features do not depend
        on the other windows)."""
        ds = self.data[spec]
        feats = clone(train_lib.make_factory(base, ds, self.seed)().features)
        key = (spec, type(feats).__name__, repr(sorted(feats.get_params().items())))
        if key not in self._features:
            self.say(f"{spec}: features of {len(ds.windows)} windows")
            feats.fit(ds.windows)
            self._features[key] = (feats, np.asarray(feats.transform(ds.windows), dtype=float))
        return self._features[key]

    def keys(self, spec: str, model: str, held: Sequence[int]) -> list[tuple]:
        return [(spec, b, frozenset(held) - {d}) for b in model.split("+") for d in held]

    def proba_of(self, spec: str, model: str, train_groups: frozenset) -> np.ndarray:
        return np.mean([self.proba[(spec, b, train_groups)] for b in model.split("+")], axis=0)

    def level_score(self, cand: Candidate, held: Sequence[int]) -> tuple[float, dict]:
        W, g = self.data[cand.spec].windows, self.gidx[cand.spec]
        per = {}
        for d in held:
            P = self.proba_of(cand.spec, cand.model, frozenset(held) - {d})
            idx = np.flatnonzero(g == d)
            idx = idx[np.isfinite(P[idx]).all(axis=1)] if len(idx) else idx
            if len(idx):
                per[int(d)] = _bal_acc(W.y[idx], P[idx], self.classes)
        return (float(np.mean(list(per.values()))) if per else float("nan")), per

    def oof(self, cand: Candidate, held: Sequence[int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Out-of-fold (labels, probabilities, run group) of a candidate at a level (windows of its groups)."""
        W, g = self.data[cand.spec].windows, self.gidx[cand.spec]
        ys, ps, gs = [], [], []
        for d in held:
            P = self.proba_of(cand.spec, cand.model, frozenset(held) - {d})
            idx = np.flatnonzero(g == d)
            idx = idx[np.isfinite(P[idx]).all(axis=1)] if len(idx) else idx
            ys.append(W.y[idx])
            ps.append(P[idx])
            gs.append(np.full(len(idx), d, dtype=np.int64))
        return np.concatenate(ys), np.concatenate(ps), np.concatenate(gs)


def _cv_classes(ds: Dataset) -> tuple[np.ndarray, dict, dict]:
    """(classes tested under grouped CV, runs per class, class id -> name) from the runs table."""
    runs = ds.runs
    lab = runs[(runs["run_class"] >= 0) & (runs["n_rows"] > 0)] if len(runs) else runs
    per = lab.groupby("run_class").size().to_dict() if len(lab) else {}
    all_names = ds.windows.attrs.get("all_class_names")
    names = {int(c): (str(all_names[int(c)]) if all_names is not None and int(c) < len(all_names)
                      else dict(zip(ds.class_ids, ds.class_names)).get(int(c), str(c))) for c in per}
    cv = np.asarray(sorted(int(c) for c, n in per.items() if n >= MIN_RUNS_PER_CLASS), dtype=np.int64)
    return cv, {int(c): int(n) for c, n in per.items()}, names


def _restrict(ds: Dataset, classes: np.ndarray, runs: np.ndarray) -> Dataset:
    W = ds.windows
    keep = np.isin(W.y, classes) & np.isin(W.groups, runs)
    if keep.all():
        return ds
    return Dataset(W.subset(np.flatnonzero(keep)), ds.runs, ds.counts, ds.robot, ds.spec, ds.preset,
                   ds.class_ids, ds.class_names, ds.class_report)


def _screen(fits: _Fits, level: Level, specs: Sequence[str], screen: str, limit_one: bool) -> list[str]:
    """The specs whose other models are fitted at this level (the others named in ``screened``)."""
    s1 = {s: fits.level_score(Candidate(s, screen), level.held)[0] for s in specs}
    level.screen_scores = dict(s1)
    fin = {s: v for s, v in s1.items() if np.isfinite(v)}
    if not fin:
        return []
    best = max(fin, key=lambda s: (fin[s], -specs.index(s)))
    keep = [s for s in specs if s in fin and fin[s] >= fin[best] - SCREEN_MARGIN]
    for s in specs:
        if s not in keep:
            level.screened[s] = (f"{screen} scored {s1[s]:.3f}, more than {SCREEN_MARGIN:.2f} below the "
                                 f"best spec ({best}: {fin[best]:.3f})")
        elif limit_one and s != best:
            level.screened[s] = "time budget: only the best spec's other models were fitted"
    return [best] if limit_one else keep


def _choose(fits: _Fits, level: Level, cands: Sequence[Candidate]) -> None:
    """Score every fitted candidate of the level and choose the best (ties: candidate order)."""
    for c in cands:
        if c.spec in level.screened:
            continue
        level.scores[c.name], level.per_group[c.name] = fits.level_score(c, level.held)
    fin = {n: v for n, v in level.scores.items() if np.isfinite(v)}
    order = list(level.scores)
    level.chosen = max(fin, key=lambda n: (fin[n], -order.index(n))) if fin else ""


def _top_cv(fits: _Fits, top: Level, cands: Sequence[Candidate], names: list, table: Any) -> dict:
    """CVResults of the top level's candidates (the ordinary grouped K-fold figures)."""
    out = {}
    for c in cands:
        if c.name not in top.scores:
            continue
        W = fits.data[c.spec].windows
        folds = folds_of_partition(W.groups, fits.partition, list(top.held))
        P = np.zeros((len(W), len(fits.classes)))
        info = []
        for d, (_, te) in zip(top.held, folds):
            key_set = frozenset(top.held) - {d}
            P[te] = fits.proba_of(c.spec, c.model, key_set)[te]
            parts = [fits.info.get((c.spec, b, key_set), {}) for b in c.bases]
            info.append({"fit_time_s": float(sum(p.get("fit_time_s", 0.0) for p in parts)),
                         "predict_time_s": float(sum(p.get("predict_time_s", 0.0) for p in parts)),
                         "n_test_groups": int(len(np.unique(W.groups[te]))),
                         "best_params": parts[0].get("best_params", {}) if len(parts) == 1 else {}})
        done = np.isfinite(P).all(axis=1)
        folds = [(tr[done[tr]], te[done[te]]) for tr, te in folds]
        out[c.name] = assemble_result(folds, W.y, fits.classes, names, np.nan_to_num(P), info, table, c.name)
    return out


def select(data: Mapping[str, Dataset], models: Sequence[str] = AUTO_MODELS, folds: int = 5, seed: int = 0,
           n_jobs: int = 1, budget_s: float | None = None, table: Any = None,
           progress: ProgressFn | None = None, nested: bool = True) -> Selection:
    """Nested run-grouped selection of a window spec and a model (see the module docstring).

    Parameters
    ----------
    data : spec name -> Dataset of the same runs (cut with that spec), in the order of preference
        on ties.
    models : model names (:func:`parse_auto_models`). folds : K, run groups. seed : of the
        partition and the models. n_jobs : joblib jobs over fits.
    budget_s : s or None. Past it after screening, only the best spec of every level gets its
        other models (said in ``budget_note``).
    table : desired-slip table for the report's slip error (or None).
    progress : callback with a short message per step and a
        :class:`~terrainml.pipeline.progress.Step` per fit (stage ``selection``; its total is
        planned from every level's fits and updated when screening drops specs).
    nested : False for a single candidate fixed beforehand (a sensor member of a chosen model):
        nothing is chosen, so its ordinary grouped K-fold CV is its honest figure and no inner
        level is fitted. Outer fold k is then the top level's fold k, and its temperature is
        fitted on the out-of-fold probabilities of the other groups (whose models did see group
        k's runs, never its labels' probabilities).

    Returns
    -------
    Selection
    """
    say = progress or (lambda msg: None)
    t_start = time.perf_counter()
    first = next(iter(data.values()))
    classes, runs_per_class, names = _cv_classes(first)
    if len(classes) < 2:
        raise ValueError(f"grouped CV needs at least 2 classes with >= {MIN_RUNS_PER_CLASS} runs; runs per "
                         f"class: { {names[c]: n for c, n in runs_per_class.items()} }; record more runs")
    runs = first.runs[first.runs["run_class"].isin(classes.tolist()) & (first.runs["n_rows"] > 0)]
    rate = float(first.spec.rate_hz)
    partition = run_partition(runs["run_id"].astype(str).to_numpy(), runs["run_class"].to_numpy(), folds, seed,
                              weights=np.round(runs["n_rows"].to_numpy() / rate).astype(np.int64))
    run_ids = np.concatenate(partition)
    infeasible, feasible = {}, {}
    for s, ds in data.items():
        d = _restrict(ds, classes, run_ids)
        why = spec_feasibility(d, classes.tolist(), names)
        if why:
            infeasible[s] = why
            say(f"{s}: not a candidate ({why})")
        else:
            feasible[s] = d
    if not feasible:
        raise ValueError("no window spec keeps enough windows of every class: " +
                         "; ".join(f"{s}: {r}" for s, r in infeasible.items()))
    models = parse_auto_models(models)
    screen = SCREEN
    cands = [Candidate(s, m) for s in feasible for m in models]
    if not nested and len(cands) != 1:
        raise ValueError(f"without nested CV there must be one candidate, got {[c.name for c in cands]}")
    K = len(partition)
    fits = _Fits(feasible, partition, classes, seed, n_jobs, say)
    top = Level(tuple(range(K)))
    inner = [Level(tuple(d for d in range(K) if d != k)) for k in range(K)]
    levels = [top, *inner] if nested else [top]
    screen_keys = ([k for lv in levels for s in feasible for k in fits.keys(s, screen, lv.held)]
                   if len(feasible) > 1 else [])  # one spec: nothing to screen
    fits.plan(screen_keys + [k for lv in levels for c in cands for k in fits.keys(c.spec, c.model, lv.held)])
    if screen_keys:
        fits.ensure(screen_keys)
    t_screen = time.perf_counter() - t_start
    over = budget_s is not None and t_screen > 0.5 * budget_s
    note = (f"screening took {t_screen / 60:.1f} min, over half the {budget_s / 60:.0f}-min budget: only the "
            "best spec of every level got its other models") if over else ""
    if over:
        say(f"note: {note}")
    specs = list(feasible)
    keys = [k for lv in levels for s in (_screen(fits, lv, specs, screen, over) if len(specs) > 1 else specs)
            for c in cands if c.spec == s for k in fits.keys(s, c.model, lv.held)]
    fits.plan(keys)  # screening decided which specs get their models
    fits.ensure(keys)
    for lv in levels:
        _choose(fits, lv, cands)
    if not nested:
        for lv in inner:
            lv.chosen = top.chosen
    if not top.chosen or any(not lv.chosen for lv in inner):
        raise ValueError("no candidate could be scored at every level (too few runs per class?)")
    by_name = {c.name: c for c in cands}
    keys = [(by_name[lv.chosen].spec, b, frozenset(lv.held)) for lv in inner for b in by_name[lv.chosen].bases]
    fits.plan(keys)  # the outer folds' models (usually fitted already at the top level)
    fits.ensure(keys)
    scored = [_outer_fold(fits, k, lv, by_name[lv.chosen], top if not nested else None) for k, lv in enumerate(inner)]
    outer = [o for o, _, _ in scored]
    outer_models = [_fitted(fits, by_name[lv.chosen], frozenset(lv.held)) for lv in inner]
    chosen = by_name[top.chosen]
    y_oof, p_oof, g_oof = fits.oof(chosen, top.held)
    temp = fit_temperature(p_oof, y_oof, g_oof, classes)
    cvs = _top_cv(fits, top, cands, [names[int(c)] for c in classes], table)
    return Selection(cands, infeasible, partition, top, inner, outer, _honest(scored), cvs, chosen,
                     temp.temperature, classes.tolist(), [names[int(c)] for c in classes],
                     {"screen_s": t_screen, "total_s": time.perf_counter() - t_start, "fits": fits.n_fits,
                      "fit_s": fits.fit_s}, note, outer_models, nested)


def _fitted(fits: _Fits, cand: Candidate, train_groups: frozenset) -> Any:
    members = [fits.models.get((cand.spec, b, train_groups)) for b in cand.bases]
    if any(m is None for m in members):
        return None
    return members[0] if len(members) == 1 else ProbabilityAverage.from_fitted(members)


def fit_temperature(proba: np.ndarray, y: np.ndarray, groups: np.ndarray, classes: np.ndarray) -> Temperature:
    """The temperature of out-of-fold probabilities, kept only where it calibrates runs it never saw.

    For each run group ``d``, a temperature is fitted on the other groups' rows and applied to
    group ``d``'s; the temperature fitted on all rows is kept when the window-weighted ECE of the
    groups is lower after than before, else T = 1 (a likelihood fit chases the few confident
    errors of some runs and can soften the right answers of the others).

    Parameters
    ----------
    proba : ndarray (n, K), out-of-fold probabilities, columns in ``classes`` order.
    y : ndarray (n,), labels. groups : ndarray (n,), the run group of each row. classes : (K,).
    """
    full = Temperature.fit(proba, y, classes)
    ids = np.unique(groups)
    if len(ids) < 2 or full.temperature == 1.0:
        return full
    before = after = 0.0
    for d in ids:
        te = groups == d
        t = Temperature.fit(proba[~te], y[~te], classes)
        before += te.sum() * expected_calibration_error(y[te], proba[te], classes)
        after += te.sum() * expected_calibration_error(y[te], t.transform(proba[te]), classes)
    return full if after < before else Temperature(1.0)


def _honest(scored: list) -> dict:
    """{mean, std} of the outer folds' balanced accuracies and ``pooled`` over their windows together."""
    vals = [o["balanced_accuracy"] for o, _, _ in scored if np.isfinite(o["balanced_accuracy"])]
    y = np.concatenate([y for _, y, _ in scored]) if scored else np.array([])
    pred = np.concatenate([p for _, _, p in scored]) if scored else np.array([])
    with warnings.catch_warnings():  # a class absent from every held-out group
        warnings.simplefilter("ignore")
        pooled = float(balanced_accuracy_score(y, pred)) if len(y) else float("nan")
    return {"mean": float(np.mean(vals)) if vals else float("nan"),
            "std": float(np.std(vals)) if vals else float("nan"), "pooled": pooled}


def _outer_fold(fits: _Fits, k: int, level: Level, cand: Candidate,
                top: Level | None = None) -> tuple[dict, np.ndarray, np.ndarray]:
    """The level-k winner fitted without group k, scored on group k; ECE before/after calibration.

    The temperature is fitted on the level's out-of-fold probabilities, or with ``top`` (no
    nested CV) on the top level's out-of-fold probabilities of the groups other than k.
    Returns the fold's figures and its held-out labels and predicted labels (for the pooled figure).
    """
    W, g = fits.data[cand.spec].windows, fits.gidx[cand.spec]
    P = fits.proba_of(cand.spec, cand.model, frozenset(level.held))
    idx = np.flatnonzero(g == k)
    idx = idx[np.isfinite(P[idx]).all(axis=1)] if len(idx) else idx
    if top is None:
        y_in, p_in, g_in = fits.oof(cand, level.held)
    else:
        y_in, p_in, g_in = fits.oof(cand, top.held)
        y_in, p_in, g_in = y_in[g_in != k], p_in[g_in != k], g_in[g_in != k]
    temp = fit_temperature(p_in, y_in, g_in, fits.classes)
    out = {"fold": k, "chosen": cand.name, "n_windows": int(len(idx)), "temperature": temp.temperature,
           "runs": [str(r) for r in fits.partition[k]], "inner_score": level.scores.get(cand.name)}
    y = W.y[idx]
    pred = fits.classes[np.argmax(P[idx], axis=1)] if len(idx) else y
    if len(idx) == 0:
        return ({**out, "balanced_accuracy": float("nan"), "ece_before": float("nan"), "ece_after": float("nan")},
                y, pred)
    return ({**out, "balanced_accuracy": _bal_acc(y, P[idx], fits.classes),
             "ece_before": expected_calibration_error(y, P[idx], fits.classes),
             "ece_after": expected_calibration_error(y, temp.transform(P[idx]), fits.classes)}, y, pred)
