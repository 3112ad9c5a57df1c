"""Temperature scaling (terrainml.models.calibration) against probabilities of a known temperature."""

import numpy as np
import pytest
from scipy.special import softmax

from terrainml.evaluation.metrics import expected_calibration_error
from terrainml.models.calibration import CalibratedModel, Temperature


def _overconfident(n=4000, k=4, t_true=2.5, seed=0):
    """Labels drawn from softmax(z); the 'model' reports softmax(t_true z): over-confident by t_true."""
    rng = np.random.default_rng(seed)
    z = rng.normal(0.0, 1.5, size=(n, k))
    p_true = softmax(z, axis=1)
    y = np.array([rng.choice(k, p=p) for p in p_true])
    return softmax(t_true * z, axis=1), y, np.arange(k)


def test_fit_recovers_the_temperature_of_overconfident_probabilities():
    proba, y, classes = _overconfident(t_true=2.5)
    t = Temperature.fit(proba, y, classes)
    assert t.temperature == pytest.approx(2.5, rel=0.1)
    cal = t.transform(proba)
    assert np.allclose(cal.sum(axis=1), 1.0)
    assert np.array_equal(cal.argmax(axis=1), proba.argmax(axis=1))  # the served class is kept
    assert expected_calibration_error(y, cal, classes) < 0.5 * expected_calibration_error(y, proba, classes)


def test_calibrated_probabilities_are_left_alone():
    proba, y, classes = _overconfident(t_true=1.0, seed=1)
    assert Temperature.fit(proba, y, classes).temperature == pytest.approx(1.0, abs=0.1)


def test_sharpening_is_bounded_when_every_window_is_right():
    proba = np.array([[0.7, 0.3], [0.2, 0.8]] * 50)
    y = np.array([0, 1] * 50)
    assert Temperature.fit(proba, y, [0, 1]).temperature == pytest.approx(0.5, abs=1e-3)


def test_labels_outside_the_classes_are_ignored_and_empty_input_is_the_identity():
    proba, y, classes = _overconfident(n=500)
    y2 = y.copy()
    y2[:10] = 99
    t = Temperature.fit(proba, y2, classes)
    assert t.temperature == pytest.approx(Temperature.fit(proba[10:], y[10:], classes).temperature, rel=1e-3)
    assert Temperature.fit(np.zeros((0, 4)), [], classes).temperature == 1.0


def test_manifest_entry_round_trip_and_refusals():
    t = Temperature(1.7)
    assert Temperature.from_dict(t.to_dict()).temperature == 1.7
    for bad in ({"method": "isotonic"}, {"method": "temperature", "temperature": -1.0},
                {"method": "temperature"}):
        with pytest.raises(ValueError):
            Temperature.from_dict(bad)


class _Fixed:
    classes_ = np.array([3, 5])

    def predict_proba(self, X):
        return np.tile([0.9, 0.1], (len(X), 1))

    best_params_ = {"C": 1.0}


def test_calibrated_model_scales_the_wrapped_probabilities():
    m = CalibratedModel(_Fixed(), Temperature(2.0))
    p = m.predict_proba(np.zeros((2, 1)))
    # softmax(log p / 2) = sqrt(p) normalised: sqrt(.9) / (sqrt(.9) + sqrt(.1)) = 0.75
    assert p[0, 0] == pytest.approx(0.75)
    assert m.predict(np.zeros((1, 1))).tolist() == [3]
    assert m.best_params_ == {"C": 1.0}
