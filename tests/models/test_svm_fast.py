"""SVMClassifier's numpy inference path against sklearn itself (the reference): decision values,
calibrated probabilities one window at a time and in batches, persistence, fallbacks."""

from __future__ import annotations

import numpy as np
import pytest
import skops.io as sio
from sklearn.calibration import CalibratedClassifierCV

from terrainml.features.sets import FeatureSet
from terrainml.features.windows import Windows
from terrainml.models import svm as svm_mod
from terrainml.models.artifacts import ALLOWED_SKOPS_TYPES
from terrainml.models.svm import SVMClassifier

CH = ("slip_1", "slip_2", "slip_3", "current_1", "current_2", "current_3", "vx", "vy", "r",
      "imu_ax", "imu_ay", "imu_az")
SMALL = {"C_grid": (10.0,), "gamma_grid": ("scale",), "selector_trees": 40}


def _windows(classes=(0, 3, 5), runs=3, per_run=6, seed=0) -> Windows:
    """Class-dependent raw windows: slip, current and imu_az roughness grow with the class,
    wheels sometimes driven backwards; overlapping classes so that decisions are not trivial."""
    import pandas as pd

    rng = np.random.default_rng(seed)
    t = np.arange(200) / 100.0
    X, y, g = [], [], []
    for c in classes:
        for r in range(runs):
            sense = rng.choice([-1.0, 1.0], size=3)
            for _ in range(per_run):
                x = np.empty((len(CH), 200))
                s = 0.02 + 0.04 * c + 0.05 * rng.standard_normal()
                for i in range(3):
                    x[i] = s + 0.01 * rng.standard_normal(200)
                    x[3 + i] = sense[i] * (2.0 + 0.8 * c + rng.normal(0, 1.0)) + 0.3 * rng.standard_normal(200)
                x[6] = rng.uniform(0.5, 1.2) + 0.02 * rng.standard_normal(200)
                x[7:11] = 0.05 * rng.standard_normal((4, 200))
                x[11] = 9.81 + (0.1 + 0.05 * c) * np.sin(2 * np.pi * (5 + 2 * c) * t) \
                    + 0.2 * rng.standard_normal(200)
                X.append(x)
                y.append(c)
                g.append(f"c{c}_r{r}")
    meta = pd.DataFrame({"run_id": g, "terrain": y, "t_start_s": 0.0, "t_end_s": 2.0, "start_index": 0})
    return Windows(np.asarray(X), CH, meta)


@pytest.fixture(scope="module")
def data3():
    w = _windows()
    m = SVMClassifier(FeatureSet(), **SMALL).fit(w, w.y)
    return m, w, _windows(seed=1)


@pytest.fixture(scope="module")
def data2():
    w = _windows(classes=(2, 7))
    m = SVMClassifier(FeatureSet(), **SMALL).fit(w, w.y)
    return m, w, _windows(classes=(2, 7), seed=1)


def _sklearn_proba(m, w):
    return m.model_.predict_proba(m.transform_features(w))


def _sklearn_decision(m, F):
    return m.model_.calibrated_classifiers_[0].estimator.decision_function(F)


@pytest.mark.parametrize("name", ["data3", "data2"])
def test_decision_values_equal_sklearn(name, request):
    m, _, test = request.getfixturevalue(name)
    c = m._compiled()
    assert c is not None and c.n_classes == len(m.classes_)
    F = m.transform_features(test)
    ref = _sklearn_decision(m, F)
    got = svm_mod._decision(c, F)
    assert got.shape == ref.shape
    np.testing.assert_allclose(got, ref, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("name", ["data3", "data2"])
def test_probabilities_equal_sklearn_in_batches_and_one_window_at_a_time(name, request):
    m, _, test = request.getfixturevalue(name)
    ref = _sklearn_proba(m, test)
    np.testing.assert_allclose(m.predict_proba(test), ref, rtol=0, atol=1e-12)
    one = np.concatenate([m.predict_proba(test.subset([k])) for k in range(len(test))])
    np.testing.assert_allclose(one, ref, rtol=0, atol=1e-12)
    raw = np.concatenate([m.predict_proba(np.asarray(test.X)[k:k + 1]) for k in range(3)])  # plain arrays
    np.testing.assert_allclose(raw, ref[:3], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(m.predict(test), m.classes_[ref.argmax(axis=1)])


def test_pipeline_windows_from_logs_equal_sklearn(dataset):
    """Windows of the real chain (ingest, EKF, window rules), the trained model's features."""
    w = dataset.windows
    m = SVMClassifier(**{k: v for k, v in SMALL.items() if k != "selector_trees"}).fit(w, w.y)
    F = m.transform_features(w)
    np.testing.assert_allclose(svm_mod._decision(m._compiled(), F), _sklearn_decision(m, F), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(m.predict_proba(w), _sklearn_proba(m, w), rtol=0, atol=1e-12)


def test_one_window_never_goes_through_sklearn(data3, monkeypatch):
    m, _, test = data3
    ref = _sklearn_proba(m, test.subset([0]))
    m._compiled()

    def boom(*a, **k):
        raise AssertionError("sklearn called in the hot path")

    monkeypatch.setattr(m.model_, "predict_proba", boom)
    monkeypatch.setattr(m.model_.calibrated_classifiers_[0].estimator, "decision_function", boom)
    np.testing.assert_allclose(m.predict_proba(test.subset([0])), ref, rtol=0, atol=1e-12)


def test_kernel_blocks_give_the_same_numbers(data3, monkeypatch):
    m, _, test = data3
    ref = m.predict_proba(test)
    monkeypatch.setattr(svm_mod, "KERNEL_CHUNK_ELEMENTS", 7)  # a few windows per block
    np.testing.assert_allclose(m.predict_proba(test), ref, rtol=0, atol=1e-15)


def test_non_finite_window_is_refused_as_by_sklearn(data3):
    m, _, test = data3
    X = np.array(test.X[:2])
    X[1, CH.index("imu_az"), 3] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        m.predict_proba(X)
    with pytest.raises(ValueError, match="expected channels"):
        m.predict_proba(X[:, :-1])  # a channel short


def test_persisted_model_holds_no_derived_arrays_and_predicts_the_same(data3, tmp_path):
    m, _, test = data3
    p = m.predict_proba(test)  # builds the numpy form
    assert "_compiled_svm" in m.__dict__ and "_compiled_svm" not in m.__getstate__()
    path = tmp_path / "m.skops"
    sio.dump(m, path)
    untrusted = set(sio.get_untrusted_types(file=path))
    assert untrusted <= ALLOWED_SKOPS_TYPES, untrusted - ALLOWED_SKOPS_TYPES
    back = sio.load(path, trusted=sorted(untrusted))
    assert "_compiled_svm" not in back.__dict__
    np.testing.assert_array_equal(back.predict_proba(test), p)


def test_refit_rebuilds_the_numpy_form(data3):
    m, train, test = data3
    m2 = SVMClassifier(FeatureSet(), **SMALL).fit(train, train.y)
    first = m2._compiled()
    m2.predict_proba(test)
    m2.set_params(C_grid=(1.0,)).fit(test, test.y)  # other data, other model
    assert m2._compiled() is not first
    np.testing.assert_allclose(m2.predict_proba(train), _sklearn_proba(m2, train), rtol=0, atol=1e-12)


def test_other_model_shapes_fall_back_to_sklearn(data3, monkeypatch):
    m, train, test = data3
    m3 = SVMClassifier(FeatureSet(), **SMALL).fit(train, train.y)
    F = m3.transform_features(train)
    base = m3.model_.calibrated_classifiers_[0].estimator
    m3.model_ = CalibratedClassifierCV(base, method="isotonic", cv=3, ensemble=False).fit(F, train.y)
    assert m3._compiled() is None
    np.testing.assert_allclose(m3.predict_proba(test), _sklearn_proba(m3, test), rtol=0, atol=1e-15)
    # a transcription that disagrees with the installed sklearn is never used
    m4 = SVMClassifier(FeatureSet(), **SMALL).fit(train, train.y)
    real = svm_mod._decision
    monkeypatch.setattr(svm_mod, "_decision", lambda c, F: real(c, F) + 1e-6)
    assert m4._compiled() is None
    np.testing.assert_allclose(m4.predict_proba(test), _sklearn_proba(m4, test), rtol=0, atol=1e-12)



class _MeanStd:
    """A plain stateless transformer (not a FeatureSet): per-channel mean and std."""

    def fit(self, X, y=None):
        self.channel_names_ = list(X.channels)
        return self

    def transform(self, X):
        A = np.asarray(getattr(X, "X", X), dtype=float)
        return np.concatenate((A.mean(axis=2), A.std(axis=2)), axis=1)

    def fit_transform(self, X, y=None):
        return self.fit(X).transform(X)

    def get_params(self, deep=True):
        return {}

    def set_params(self, **params):
        return self


def test_other_feature_transformers_use_the_numpy_svm_too(data3):
    _, train, test = data3
    m = SVMClassifier(_MeanStd(), **SMALL).fit(train, train.y)
    c = m._compiled()
    assert c is not None and c.columns is None and c.n_features == int(m.feature_mask_.sum())
    np.testing.assert_allclose(m.predict_proba(test), _sklearn_proba(m, test), rtol=0, atol=1e-12)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_kernel_search_gives_the_scores_and_choice_of_sklearns_grid_search(seed):
    """The C/gamma search on precomputed kernels (svm._kernel_search) against GridSearchCV on the
    same pipeline, grid and grouped splits: every mean inner score and the chosen parameters."""
    from sklearn.model_selection import GridSearchCV

    rng = np.random.default_rng(seed)
    n, d = 240, 12
    y = np.repeat([0, 1, 2], n // 3)
    groups = np.repeat(np.arange(12), n // 12)  # 4 runs per class
    F = rng.normal(0.0, 1.0, (n, d)) * rng.uniform(0.5, 5.0, d) + rng.uniform(-3, 3, d)
    F[:, :3] += 0.8 * y[:, None] * rng.uniform(0.5, 1.5, 3)  # overlapping classes: scores below 1
    splits = svm_mod.inner_splits(y, groups, 3, seed)
    Cs, gammas = [0.3, 3.0, 30.0], ["scale", 0.01, 0.1]
    best, score = svm_mod._kernel_search(F, y, splits, Cs, gammas)
    ref = GridSearchCV(SVMClassifier()._pipeline(), {"svc__C": Cs, "svc__gamma": gammas},
                       scoring="balanced_accuracy", cv=splits, refit=False).fit(F, y)
    assert best == {"C": ref.best_params_["svc__C"], "gamma": ref.best_params_["svc__gamma"]}
    assert score == pytest.approx(ref.best_score_, abs=1e-12)
    assert 0.4 < score < 0.99  # a search that can fail: classes overlap


def test_svm_above_the_kernel_search_size_uses_sklearns_search(data3, monkeypatch):
    """Both searches choose the same parameters on the same windows."""
    W = data3[1]
    kw = {"C_grid": (1.0, 100.0), "gamma_grid": ("scale", 0.001), "selector_trees": 40}
    a = SVMClassifier(**kw).fit(W, W.y)
    monkeypatch.setattr(svm_mod, "KERNEL_SEARCH_MAX_WINDOWS", 1)
    b = SVMClassifier(**kw).fit(W, W.y)
    assert a.best_params_ == b.best_params_ and a.inner_score_ == pytest.approx(b.inner_score_, abs=1e-12)
