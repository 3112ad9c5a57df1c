"""CNNClassifier: learning, generality (classes, channels), determinism, normalisation, params."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from sklearn.base import clone
from sklearn.metrics import balanced_accuracy_score

from terrainml.models.cnn import CNNClassifier
from terrainml.models.cnn_training import inner_split as _inner_split


def test_learns_frequency_class_on_held_out_runs(fitted):
    clf, X, y, g, train = fitted
    pred = clf.predict(X[~train])
    assert balanced_accuracy_score(y[~train], pred) >= 0.95
    proba = clf.predict_proba(X[~train])
    assert proba.shape == (int((~train).sum()), 3)
    np.testing.assert_allclose(proba.sum(axis=1), 1.0, atol=1e-6)
    assert list(clf.classes_) == [0, 1, 2]


def test_learns_mean_class_two_classes_string_labels_20_channels(window_factory):
    X, y, g = window_factory(n_classes=2, n_channels=20, runs_per_class=5, windows_per_run=6,
                             kind="mean", seed=7)
    labels = np.where(y == 0, "pavement", "wet_mud")
    run_no = np.array([int(s[3:]) for s in g])
    train = (run_no % 5) < 4
    clf = CNNClassifier.from_params(random_state=3, max_epochs=15, n_threads=1,
                        channel_names=[f"c{i}" for i in range(20)])
    clf.fit(X[train], labels[train], g[train])
    assert list(clf.classes_) == ["pavement", "wet_mud"]
    assert clf.n_channels_in_ == 20 and clf.channel_names_[19] == "c19"
    pred = clf.predict(X[~train])
    assert pred.dtype.kind == "U"
    assert balanced_accuracy_score(labels[~train], pred) >= 0.95
    assert clf.predict_proba(X[~train]).shape == (int((~train).sum()), 2)


def test_same_seed_identical_weights_and_predictions(freq_data):
    X, y, g = freq_data
    sub = slice(0, None, 2)
    kw = dict(random_state=11, max_epochs=4, n_threads=1)
    a = CNNClassifier.from_params(**kw).fit(X[sub], y[sub], g[sub])
    b = CNNClassifier.from_params(**kw).fit(X[sub], y[sub], g[sub])
    c = CNNClassifier.from_params(**{**kw, "random_state": 12}).fit(X[sub], y[sub], g[sub])
    sa, sb, sc = (m.model_.state_dict() for m in (a, b, c))
    assert all(torch.equal(sa[k], sb[k]) for k in sa)
    assert np.array_equal(a.predict_proba(X), b.predict_proba(X))
    assert a.history_ == b.history_
    # a different seed really changes the training (so the check above can fail)
    assert not all(torch.equal(sa[k], sc[k]) for k in sa)


def test_fit_leaves_global_torch_state_alone(freq_data):
    X, y, g = freq_data
    torch.manual_seed(1234)
    rng_before = torch.get_rng_state()
    threads_before = torch.get_num_threads()
    det_before = torch.are_deterministic_algorithms_enabled()
    seen = []
    real_set = torch.set_num_threads

    def spy(n):
        seen.append(n)
        real_set(n)

    torch.set_num_threads = spy
    try:
        CNNClassifier.from_params(random_state=0, max_epochs=1, n_threads=1).fit(X[::4], y[::4], g[::4])
    finally:
        torch.set_num_threads = real_set
    assert seen and seen[0] == 1  # n_threads applied ...
    assert torch.get_num_threads() == threads_before  # ... and restored
    assert torch.equal(torch.get_rng_state(), rng_before)
    assert torch.are_deterministic_algorithms_enabled() == det_before


def test_normalisation_statistics_come_from_training_data_only(fitted):
    clf, X, y, g, train = fitted
    Xtr = X[train].astype(np.float64)
    np.testing.assert_allclose(clf.mean_, Xtr.mean(axis=(0, 2)), rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(clf.scale_, Xtr.std(axis=(0, 2)), rtol=1e-5)
    # test data of another distribution does not move them
    mean_before = clf.mean_.copy()
    clf.predict_proba(X[~train] + 100.0)
    np.testing.assert_array_equal(clf.mean_, mean_before)
    all_mean = X.astype(np.float64).mean(axis=(0, 2))
    assert not np.allclose(clf.mean_, all_mean, rtol=1e-5, atol=1e-5)


def test_normalisation_ignores_missing_samples_and_constant_channels(window_factory):
    X, y, g = window_factory(n_classes=2, runs_per_class=3, windows_per_run=4, seed=5)
    X = X.copy()
    X[:, 0, :50] = np.nan          # e.g. slip while the camera was out
    X[:, 1, :] = 9.81               # a constant channel
    X[:, 2, :] = np.nan             # an all-missing channel (robot without camera)
    clf = CNNClassifier.from_params(random_state=0, max_epochs=2, n_threads=1).fit(X, y, g)
    expected0 = np.nanmean(X[:, 0, :].astype(np.float64))
    assert clf.mean_[0] == pytest.approx(expected0, rel=1e-5)
    assert clf.scale_[0] == pytest.approx(np.nanstd(X[:, 0, :].astype(np.float64)), rel=1e-5)
    assert clf.mean_[1] == pytest.approx(9.81, rel=1e-6) and clf.scale_[1] == 1.0
    assert clf.mean_[2] == 0.0 and clf.scale_[2] == 1.0
    assert np.all(np.isfinite(clf.predict_proba(X)))


def test_inner_validation_split_never_splits_a_run(freq_data):
    _, y, g = freq_data
    for seed in range(5):
        tr, va = _inner_split(y, g, 0.2, seed)
        assert len(va) > 0
        assert set(g[tr]).isdisjoint(set(g[va]))
        assert len(tr) + len(va) == len(y)
        assert set(y[va]) == set(y)  # stratified: every class is validated
    # few runs: GroupShuffleSplit fallback, still grouped
    few = np.repeat(["a", "b", "c"], 5)
    tr, va = _inner_split(np.repeat([0, 1, 0], 5), few, 0.2, 0)
    assert len(va) and set(few[tr]).isdisjoint(set(few[va]))


@pytest.mark.parametrize("params, match", [
    ({"conv_channels": (32, 64), "kernel_sizes": (7, 5, 3)}, "same length"),
    ({"kernel_sizes": (6, 5, 3)}, "odd"),
    ({"dropout": 1.5}, "dropout"),
    ({"learning_rate": 0.0}, "learning_rate"),
    ({"batch_size": 1}, "batch_size"),
    ({"validation_fraction": 0.9}, "validation_fraction"),
    ({"class_weight": "weird"}, "class_weight"),
    ({"n_threads": 0}, "n_threads"),
    ({"channel_names": ["a", "b"]}, "channel_names"),
])
def test_bad_params_are_refused_at_fit(freq_data, params, match):
    X, y, g = freq_data
    clf = CNNClassifier.from_params(**params)  # constructing never fails (sklearn convention)
    with pytest.raises(ValueError, match=match):
        clf.fit(X[::12], y[::12], g[::12])


def test_bad_inputs_are_refused(fitted):
    clf, X, y, g, train = fitted
    with pytest.raises(ValueError, match="shape"):
        CNNClassifier().fit(X[:, 0, :], y)
    with pytest.raises(ValueError, match="2 classes"):
        CNNClassifier().fit(X[:10], np.zeros(10), g[:10])
    with pytest.raises(ValueError, match="groups"):
        CNNClassifier().fit(X[:10], y[:10], g[:9])
    with pytest.raises(ValueError, match="channels"):
        clf.predict(X[:, :5, :])


def test_clone_and_get_params_roundtrip():
    clf = CNNClassifier.from_params(conv_channels=(8, 8), kernel_sizes=(3, 3), random_state=4)
    other = clone(clf)
    assert other.get_params() == clf.get_params()


def test_windows_input_carries_channel_names_and_runs(window_factory):
    windows_mod = pytest.importorskip("terrainml.features.windows")
    import pandas as pd

    X, y, g = window_factory(n_classes=2, n_channels=5, runs_per_class=4, windows_per_run=6,
                             kind="mean", seed=9)
    names = ("slip_1", "current_1", "vx", "imu_az", "r")
    meta = pd.DataFrame({"run_id": g, "terrain": y, "t_start_s": 0.0, "t_end_s": 2.0,
                         "start_index": 0})
    win = windows_mod.Windows(X.astype(np.float64), names, meta)
    clf = CNNClassifier.from_params(random_state=0, max_epochs=3, n_threads=1).fit(win, win.y)
    assert clf.channel_names_ == list(names)
    reordered = win.select_channels(list(reversed(names)))
    np.testing.assert_array_equal(clf.predict_proba(reordered), clf.predict_proba(X))
    with pytest.raises(ValueError, match="slip_1"):
        clf.predict_proba(win.select_channels(["current_1", "vx", "imu_az", "r"]))


def test_inner_split_keeps_every_class_in_training():
    # class 1 has a single run: it must stay in the inner training part for every seed
    y = np.array([0] * 40 + [1] * 5)
    groups = np.array([f"r{i // 5}" for i in range(40)] + ["single"] * 5)
    for seed in range(10):
        tr, va = _inner_split(y, groups, 0.2, seed)
        assert 1 in set(y[tr])
        assert set(groups[tr]).isdisjoint(set(groups[va]))
        assert len(tr) + len(va) == len(y)


def test_refit_uses_every_window_for_the_chosen_epochs(freq_data):
    X, y, g = freq_data
    sub = slice(0, None, 3)
    clf = CNNClassifier.from_params(random_state=0, max_epochs=6, patience=3, refit=True, n_threads=1)
    clf.fit(X[sub], y[sub], g[sub])
    assert len(clf.refit_history_) == clf.best_epoch_
    assert all(np.isnan(r["val_loss"]) for r in clf.refit_history_)  # no validation in the refit
    assert len(clf.history_) == clf.n_epochs_ >= clf.best_epoch_
