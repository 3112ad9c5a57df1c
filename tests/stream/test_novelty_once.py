"""One classification computes the model's features once, for its probabilities and its novelty.

Truth: the offline path, computed apart from serving: the novelty score of
``scorer.score(model_features(model, windows))`` (the features the scorer was fitted on, all of
the feature set then the SVM's selection: another computation than the SVM's selected columns
of serving) and the two-call serving of before, ``model.predict_proba(windows)``, both exactly;
the probabilities also from sklearn's fitted estimators on those features, the average and the
temperature written out here (to 1e-12: the SVM's numpy form is sklearn's to that). The windows
are real serving windows (kinematic runs through the estimator) of a drive that leaves the
trained ground for a slip no class has, so some windows are flagged.
"""

from __future__ import annotations

import numpy as np
import pytest
from stream_fakes import SLIP_OF

import terrainml.features.sets as sets
from terrainml.estimation.run import estimate_run
from terrainml.features.sets import FeatureSet
from terrainml.features.windows import Windows, WindowSpec, cut_windows
from terrainml.models.calibration import CalibratedModel, Temperature
from terrainml.models.ensemble import ProbabilityAverage
from terrainml.models.novelty import NoveltyError, fit_model_novelty, model_features, proba_and_features
from terrainml.models.svm import SVMClassifier
from terrainml.models.trees import BoostedTrees, to_bins
from terrainml.robot import load_robot
from terrainml.stream.tick.classify import WindowClassifier
from terrainml.testing import kinematic_run, trapezoid_speed

ROBOT = load_robot()
SPEC = WindowSpec(window_s=1.0)
KNOWN = (0, 2)
T_CAL = 1.7
NAMES = ("svm", "hgb", "svm+hgb", "hgb+svm")


def _estimated(slip, seed, run_id, terrain=0, duration_s=40.0):
    """Estimator rows of a simulated kinematic run (the trapezoid speed of the stream tests)."""
    table = kinematic_run(ROBOT, duration_s=duration_s, slip=slip, terrain=terrain, seed=seed, imu_acc_noise=0.005,
                          vx=lambda t: trapezoid_speed(t, 1.0, 1.0, 1.0), run_id=run_id)
    return estimate_run(table, ROBOT)


@pytest.fixture(scope="module")
def fitted():
    """svm and hgb on two slip levels, their averages both ways round, and a scorer for each."""
    W = Windows.concat([cut_windows(_estimated(SLIP_OF[c], 500 + 10 * c + r, f"c{c}r{r}", c), ROBOT,
                                    spec=SPEC)[0] for c in KNOWN for r in range(3)])
    svm = SVMClassifier(FeatureSet.for_robot(ROBOT), C_grid=[10.0], gamma_grid=["scale"],
                        inner_folds=2).fit(W, W.y)
    hgb = BoostedTrees(FeatureSet.for_robot(ROBOT), max_iter=30).fit(W, W.y)
    models = {"svm": svm, "hgb": hgb, "svm+hgb": ProbabilityAverage.from_fitted([svm, hgb]),
              "hgb+svm": ProbabilityAverage.from_fitted([hgb, svm])}
    scorers = {"svm": fit_model_novelty(svm, W, seed=0)[0], "hgb": fit_model_novelty(hgb, W, seed=0)[0]}
    return models, scorers


@pytest.fixture(scope="module")
def drive():
    """Estimator columns of a drive: trained slip, a slip far from both classes, trained again."""
    est = _estimated(lambda t: 0.45 if 12.0 <= t < 24.0 else SLIP_OF[0], 77, "drive", duration_s=36.0)
    return {c: est[c].to_numpy() for c in est.columns
            if c not in ("terrain", "run_id") and not c.startswith("gt_")}


def _latest(drive, n=SPEC.n_samples, hop=50):
    """The last ``n`` rows of the drive at every ``hop``-th row: what serving classifies."""
    end = len(drive["t_s"])
    return [{c: v[k - n:k] for c, v in drive.items()} for k in range(n, end + 1, hop)]


def _case(fitted, name, calibrated):
    models, scorers = fitted
    model = models[name]
    if calibrated:
        model = CalibratedModel(model, Temperature(T_CAL))
    return model, scorers[name.split("+")[0]]


def _sklearn_proba(model, wins):
    """Probabilities from sklearn's fitted estimators, the average and temperature by hand."""
    if isinstance(model, CalibratedModel):
        logp = np.log(np.clip(_sklearn_proba(model.model, wins), 1e-12, 1.0)) / model.calibrator.temperature
        e = np.exp(logp - logp.max(axis=1, keepdims=True))
        return e / e.sum(axis=1, keepdims=True)
    if isinstance(model, ProbabilityAverage):
        return sum(_sklearn_proba(m, wins) for m in model.members_) / len(model.members_)
    if isinstance(model, SVMClassifier):
        return model.model_.predict_proba(model.transform_features(wins))
    return model.model_.predict_proba(to_bins(model.features_.transform(wins), model.bin_thresholds_))


# the fast tier checks the SVM alone and the calibrated average of both models (the boosted trees
# included); the other six combinations, about 20 s of CPU each, run in `make test-all`
_FAST_CASES = {("svm", False), ("svm+hgb", True)}
_CASES = [pytest.param(n, c, id=f"{n}-{'calibrated' if c else 'raw'}",
                       marks=() if (n, c) in _FAST_CASES else pytest.mark.acceptance)
          for c in (False, True) for n in NAMES]


@pytest.mark.parametrize("name,calibrated", _CASES)
def test_serving_gives_the_two_call_probabilities_and_novelty_exactly(fitted, drive, name, calibrated):
    model, scorer = _case(fitted, name, calibrated)
    clf = WindowClassifier(model, ROBOT, None, SPEC, novelty=scorer)
    thr = float(scorer.threshold)
    n_classified = n_flagged = 0
    for cols in _latest(drive):
        p = clf.classify_columns(cols)
        wins, _ = cut_windows(cols, ROBOT, spec=SPEC, online=True)
        assert (p is None) == (len(wins) == 0)
        if p is None:
            continue
        wins = Windows(wins.X[-1:], wins.channels, None, wins.rate_hz)
        np.testing.assert_array_equal(p, np.asarray(model.predict_proba(wins), dtype=float)[-1])
        np.testing.assert_allclose(p, _sklearn_proba(model, wins)[-1], rtol=0, atol=1e-12)
        score = float(scorer.score(model_features(model, wins))[-1])
        # the SVM's served features are its fast selected-column path, the scorer's reference the offline
        # feature code: equal to 1e-12 (tests/features), so the score is compared to that, not bit for bit
        assert clf.last_novelty[0] == pytest.approx(score / thr, rel=1e-9)
        if abs(score - thr) > 1e-9 * thr:
            assert clf.last_novelty[1] == (score > thr)
        n_classified += 1
        n_flagged += score > thr
    assert n_classified >= 30 and 0 < n_flagged < n_classified


@pytest.mark.parametrize("calibrated", [False, True], ids=["raw", "calibrated"])
@pytest.mark.parametrize("name,spaces", [("svm", 1), ("hgb", 1), ("svm+hgb", 2)])
def test_one_classification_computes_each_feature_space_once(fitted, drive, monkeypatch, name, spaces,
                                                             calibrated):
    """svm and hgb: one feature matrix per window (two before: the model's and the novelty's);
    svm+hgb: one per member (their feature spaces differ), the novelty reusing the svm's."""
    model, scorer = _case(fitted, name, calibrated)
    calls = []
    flat = sets._flat_features
    monkeypatch.setattr(sets, "_flat_features", lambda *a, **k: calls.append(1) or flat(*a, **k))
    clf = WindowClassifier(model, ROBOT, None, SPEC, novelty=scorer)
    classified = [clf.classify_columns(cols) is not None for cols in _latest(drive)[:20]]
    assert sum(classified) >= 10 and len(calls) == spaces * sum(classified)
    plain = WindowClassifier(model, ROBOT, None, SPEC)  # without a scorer: as before, the model's own
    calls.clear()
    assert sum(plain.classify_columns(cols) is not None for cols in _latest(drive)[:20]) == sum(classified)
    assert len(calls) == spaces * sum(classified)


def test_a_model_without_a_feature_space_has_no_novelty_features():
    class Raw:  # a CNN's interface: probabilities of raw windows, no feature space
        classes_ = np.array([0, 1])

        def predict_proba(self, X):
            return np.full((len(X), 2), 0.5)

    with pytest.raises(NoveltyError, match="no feature space"):
        proba_and_features(CalibratedModel(Raw(), Temperature(2.0)), np.zeros((1, 3, 10)))
    with pytest.raises(NoveltyError, match="no member of the average"):
        proba_and_features(ProbabilityAverage.from_fitted([Raw(), Raw()]), np.zeros((1, 3, 10)))
