"""Temporal fusion over distance (issue #19): hand-made probability sequences with known answers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from terrainml.stream.fusion import TerrainFilter

K = 4


def _p(c: int, p: float = 0.8) -> np.ndarray:
    out = np.full(K, (1.0 - p) / (K - 1))
    out[c] = p
    return out


def test_standing_still_changes_nothing():
    f = TerrainFilter(K)
    f.update(_p(2))
    before = f.posterior.copy()
    for _ in range(1000):  # 10 s at 100 Hz standing still
        f.predict(0.0)
    np.testing.assert_array_equal(f.posterior, before)
    assert f.age_m == 0.0 and not f.stale


def test_prior_per_metre_is_exp_minus_d_over_l():
    """One class certain, d = L metres: p_stay = 1/e, the rest spread evenly."""
    f = TerrainFilter(K, length_m=5.0, eps=1e-12)
    f.posterior = np.array([1.0, 0.0, 0.0, 0.0])
    f.predict(5.0)
    assert f.posterior[0] == pytest.approx(math.exp(-1.0))
    assert f.posterior[1:] == pytest.approx([(1 - math.exp(-1.0)) / 3] * 3)


def test_ages_with_distance_and_goes_stale():
    f = TerrainFilter(K, stale_m=3.0)
    f.update(_p(1))
    for _ in range(29):
        f.predict(0.1)
    assert not f.stale and f.age_m == pytest.approx(2.9)
    f.predict(0.2)
    assert f.stale
    f.update(_p(1))
    assert f.age_m == 0.0 and not f.stale


def test_switches_fast_after_a_real_transition():
    """Class 0 for 40 windows (one per 0.1 m), then class 3: served within 5 windows (0.5 m)."""
    f = TerrainFilter(K)
    for _ in range(40):
        f.predict(0.1)
        f.update(_p(0, 0.85))
    assert f.best()[0] == 0 and f.best()[1] > 0.95
    served = []
    for _ in range(20):
        f.predict(0.1)
        f.update(_p(3, 0.85))
        served.append(f.best()[0])
    first = served.index(3)
    assert first <= 4
    assert all(c == 3 for c in served[first:])  # and stays


def test_no_chatter_on_a_noisy_constant_class():
    """The true class 1 wins 70% of windows, a wrong one the other 30% (at p 0.6): the fused
    class never leaves class 1 once it is held."""
    rng = np.random.default_rng(0)
    f = TerrainFilter(K)
    served = []
    for k in range(500):
        f.predict(0.1)
        if k == 0 or rng.random() < 0.7:
            f.update(_p(1, 0.7))
        else:
            f.update(_p(int(rng.choice([0, 2, 3])), 0.6))
        served.append(f.best()[0])
    assert all(c == 1 for c in served)
    assert f.n_changes == 0


def test_change_detector_fires_when_the_cusum_says():
    """Windows that deny the held class outright (p = 0) add ln(1 / eps) - drift nats each; with a
    near-flat temper the Bayes update barely moves, so the alarm comes at the first n with
    n (ln 20 - 2) > 12 (eps 0.05, drift 2, threshold 12) and restarts from the window."""
    f = TerrainFilter(K, alpha=0.01, eps=0.05, drift=2.0, threshold=12.0)
    f.update(_p(0, 0.85))
    deny = np.array([0.0, 0.0, 1.0, 0.0])
    fired = [f.update(deny) for _ in range(30)]
    n_expected = math.floor(12.0 / (math.log(20.0) - 2.0)) + 1
    assert fired.index(True) + 1 == n_expected
    assert f.n_changes == 1 and f.best()[0] == 2


def test_raw_argmax_would_chatter_where_the_filter_does_not():
    """The same kind of sequence: the raw argmax switches often, the fused class at most once."""
    rng = np.random.default_rng(1)
    f = TerrainFilter(K)
    raw, fused = [], []
    for k in range(300):
        c = 2 if k == 0 or rng.random() < 0.65 else int(rng.choice([0, 1, 3]))
        p = _p(c, 0.55)
        f.predict(0.1)
        f.update(p)
        raw.append(int(np.argmax(p)))
        fused.append(f.best()[0])
    assert sum(a != b for a, b in zip(raw[1:], raw[:-1])) > 50
    assert sum(a != b for a, b in zip(fused[1:], fused[:-1])) == 0


def test_settings_are_checked():
    with pytest.raises(ValueError, match="length_m"):
        TerrainFilter(K, length_m=0.0)
    with pytest.raises(ValueError, match="alpha"):
        TerrainFilter(K, alpha=1.5)
    with pytest.raises(ValueError, match="probabilities"):
        TerrainFilter(K).update(np.ones(3) / 3)
