"""Nested run-grouped selection (terrainml.pipeline.select) and the run partition it stands on."""

import numpy as np
import pytest
from sklearn.metrics import balanced_accuracy_score

from logs_synth import write_logs
from terrainml.evaluation.cv import cross_validate
from terrainml.evaluation.folds import folds_of_partition, run_partition
from terrainml.features.windows import window_spec
from terrainml.models.calibration import Temperature
from terrainml.pipeline.dataset import Dataset, build_dataset
from terrainml.pipeline.candidates import parse_auto_models
from terrainml.pipeline.select import fit_temperature, select, spec_feasibility
from terrainml.pipeline.train import make_factory


def test_run_partition_puts_every_run_in_one_group_with_every_class():
    ids = np.array([f"r{i}" for i in range(12)])
    cls = np.repeat([0, 1, 2], 4)
    parts = run_partition(ids, cls, n_splits=4, seed=3, weights=np.arange(1, 13))
    flat = np.concatenate(parts)
    assert sorted(flat.tolist()) == sorted(ids.tolist())
    for p in parts:  # 4 runs per class in 4 groups: one of each class per group
        assert sorted(cls[np.isin(ids, p)].tolist()) == [0, 1, 2]
    again = run_partition(ids, cls, n_splits=4, seed=3, weights=np.arange(1, 13))
    assert all(np.array_equal(a, b) for a, b in zip(parts, again))
    # fewer runs of a class than folds: the folds are lowered to that count
    assert len(run_partition(ids, np.r_[np.zeros(10), [1, 1]], n_splits=5)) == 2


def test_folds_of_partition_test_one_group_and_train_on_the_others():
    groups = np.array(["a", "a", "b", "c", "c", "d"])
    parts = [np.array(["a"]), np.array(["b", "d"]), np.array(["c"])]
    folds = folds_of_partition(groups, parts, held=[0, 1])
    assert [f[1].tolist() for f in folds] == [[0, 1], [2, 5]]
    assert [f[0].tolist() for f in folds] == [[2, 5], [0, 1]]  # group 2 ("c") held by no one


def test_auto_models():
    assert parse_auto_models("auto") == ["svm", "hgb", "svm+hgb"]
    assert parse_auto_models("auto,cnn") == ["svm", "hgb", "svm+hgb", "cnn"]


@pytest.fixture(scope="module")
def short_ds(tmp_path_factory):
    logs = write_logs(tmp_path_factory.mktemp("sel_logs"), runs_per_class=3, seed=4)
    return build_dataset(logs, "agrimaro", spec=window_spec("short"))


def test_a_spec_that_loses_a_class_is_not_a_candidate(short_ds):
    W = short_ds.windows
    keep = np.flatnonzero(W.y != 2)
    ds = Dataset(W.subset(keep), short_ds.runs, short_ds.counts, short_ds.robot, short_ds.spec,
                 short_ds.preset, short_ds.class_ids, short_ds.class_names, short_ds.class_report)
    why = spec_feasibility(ds, [0, 2, 6], {0: "pavement", 2: "gravel", 6: "mud"})
    assert "0 window(s) of gravel" in why
    assert spec_feasibility(short_ds, [0, 2, 6], {0: "a", 2: "b", 6: "c"}) == ""


def test_nested_figures_are_those_of_models_that_never_saw_their_test_runs(short_ds):
    sel = select({"short": short_ds}, ["hgb"], folds=3, seed=0)
    W = short_ds.windows
    assert sel.chosen.name == "short/hgb" and len(sel.partition) == 3
    # the top level is the ordinary grouped CV over the same run groups (the existing engine)
    folds = folds_of_partition(W.groups, sel.partition)
    ref = cross_validate(make_factory("hgb", short_ds, 0), W, W.y, W.groups, folds=folds)
    assert sel.cv["short/hgb"].pooled["balanced_accuracy"] == pytest.approx(ref.pooled["balanced_accuracy"])
    # outer fold k: a model fitted by hand on the other groups' runs, scored on group k's runs
    for k, o in enumerate(sel.outer):
        assert sorted(o["runs"]) == sorted(sel.partition[k].tolist())
        te = np.isin(W.groups, sel.partition[k])
        m = make_factory("hgb", short_ds, 0)()
        m.fit(W.subset(np.flatnonzero(~te)), W.y[~te], groups=W.groups[~te])
        bal = balanced_accuracy_score(W.y[te], m.predict(W.subset(np.flatnonzero(te))))
        assert o["balanced_accuracy"] == pytest.approx(bal)
        assert k not in sel.inner[k].held
    assert sel.honest["mean"] == pytest.approx(np.mean([o["balanced_accuracy"] for o in sel.outer]))
    # pooled: one balanced accuracy over every outer fold's held-out windows together (the engine's definition)
    y_all, pred_all = [], []
    for k in range(len(sel.partition)):
        te = np.isin(W.groups, sel.partition[k])
        m = make_factory("hgb", short_ds, 0)()
        m.fit(W.subset(np.flatnonzero(~te)), W.y[~te], groups=W.groups[~te])
        y_all.append(W.y[te])
        pred_all.append(m.predict(W.subset(np.flatnonzero(te))))
    assert sel.honest["pooled"] == pytest.approx(balanced_accuracy_score(np.concatenate(y_all),
                                                                         np.concatenate(pred_all)))


def test_a_temperature_is_kept_only_where_it_calibrates_run_groups_it_was_not_fitted_on():
    classes = np.arange(2)
    # near-perfect: 4 run groups of 100 windows at confidence 0.999, group 0 holds 3 errors. Likelihood on all
    # rows softens to T = log(999) / log(397 / 3) = 1.41 (hand-worked), but fitted without group 0 it sharpens
    # (no error left) and without another group it softens that group's right answers: T stays 1
    y = np.array([0, 1] * 200)
    groups = np.repeat(np.arange(4), 100)
    proba = np.where(y[:, None] == classes, 0.999, 0.001)
    proba[:3] = proba[:3, ::-1]
    assert Temperature.fit(proba, y, classes).temperature == pytest.approx(np.log(999) / np.log(397 / 3), rel=0.01)
    assert fit_temperature(proba, y, groups, classes).temperature == 1.0
    # over-confident in every run group alike (true T = 2.5): kept, as Temperature.fit gives it
    rng = np.random.default_rng(0)
    z = rng.normal(0.0, 2.0, size=(2000, 3))
    p_true = np.exp(z) / np.exp(z).sum(axis=1, keepdims=True)
    y3 = np.array([rng.choice(3, p=p) for p in p_true])
    over = np.exp(2.5 * z) / np.exp(2.5 * z).sum(axis=1, keepdims=True)
    t = fit_temperature(over, y3, rng.integers(0, 4, size=2000), np.arange(3)).temperature
    assert t == pytest.approx(2.5, rel=0.1)
    assert t == Temperature.fit(over, y3, np.arange(3)).temperature


def test_a_fixed_candidate_gets_its_grouped_cv_without_inner_levels(short_ds):
    """nested=False (a sensor member): K fits on K - 1 groups, the outer folds are the top level's
    folds, and fold k's temperature never sees group k's probabilities."""
    sel = select({"short": short_ds}, ["hgb"], folds=3, seed=0, nested=False)
    W = short_ds.windows
    assert sel.timing_s["fits"] == 3 and not sel.nested
    assert all(lv.chosen == "short/hgb" and not lv.scores for lv in sel.inner)
    for k, o in enumerate(sel.outer):
        te = np.isin(W.groups, sel.partition[k])
        m = make_factory("hgb", short_ds, 0)()
        m.fit(W.subset(np.flatnonzero(~te)), W.y[~te], groups=W.groups[~te])
        assert o["balanced_accuracy"] == pytest.approx(
            balanced_accuracy_score(W.y[te], m.predict(W.subset(np.flatnonzero(te)))))
        assert o["balanced_accuracy"] == pytest.approx(sel.cv["short/hgb"].fold_metrics[k]["balanced_accuracy"])
    with pytest.raises(ValueError, match="one candidate"):
        select({"short": short_ds}, ["hgb", "svm"], folds=3, nested=False)
