"""Temporal fusion over distance: hand-made probability sequences with known answers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from terrainml.features.windows import WindowSpec
from terrainml.stream.tick.fusion import FusionConfig, TerrainFilter, confirm_windows_for

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


@pytest.mark.parametrize("confirm", [1, 3])
def test_switches_fast_after_a_real_transition(confirm):
    """Class 0 for 40 windows (one per 0.1 m), then class 3 at p 0.85. Hand-worked: each class-3
    window adds -ln(0.05 + 0.02) - 1.5 = 1.16 nats to the CUSUM of the held class 0, so the alarm
    (> 4 nats) comes on the 4th window (index 3), before the tempered Bayes update alone would
    have moved the posterior (odds 57:1 for class 0, / 2.4 per window); with K = ``confirm``
    windows to agree, class 3 is served from index 3 + K - 1 on, and stays."""
    f = TerrainFilter(K, confirm_windows=confirm)
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
    assert first == 3 + confirm - 1
    assert all(c == 0 for c in served[:first])  # the class from before is held meanwhile
    assert all(c == 3 for c in served[first:])  # and the new one stays
    assert f.n_changes == 1 and not f.pending


def test_a_third_class_from_straddling_windows_is_not_served():
    """Class 0, then 4 windows naming a third class 2 (a window straddling a 0 -> 3 transition;
    the alarm comes on the 4th, as above), then class 3. Confirming over 3 windows serves 0 until
    class 3 is confirmed: one switch, never class 2; restarting at once (K = 1) serves class 2."""
    def run(confirm):
        f = TerrainFilter(K, confirm_windows=confirm)
        served = []
        for c, n in ((0, 40), (2, 4), (3, 20)):
            for _ in range(n):
                f.predict(0.1)
                f.update(_p(c, 0.85))
                served.append(f.best()[0])
        return served

    served = run(3)
    assert set(served) == {0, 3} and sum(a != b for a, b in zip(served[1:], served[:-1])) == 1
    assert served.index(3) == 44 + 2  # the 3rd class-3 window confirms it
    assert 2 in run(1)


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
    for bad in (0, 1.5):
        with pytest.raises(ValueError, match="confirm_windows"):
            TerrainFilter(K, confirm_windows=bad)


def test_the_predictor_confirms_over_a_fifth_of_a_second(fake_predictor):
    """0.2 s of windows after the alarm one: 3 windows at the ``short`` spec's 0.1 s hop, none at
    a 0.5 s hop (``steady``, ``chunks``), unless the caller says otherwise."""
    assert confirm_windows_for(0.1) == 3 and confirm_windows_for(0.5) == 1
    short, steady = WindowSpec(online_hop_s=0.1), WindowSpec(online_hop_s=0.5)
    assert fake_predictor(window_spec=short).filter.confirm_windows == 3
    assert fake_predictor(window_spec=steady).filter.confirm_windows == 1
    assert fake_predictor(window_spec=short, fusion=FusionConfig(confirm_windows=1)).filter.confirm_windows == 1
    with pytest.raises(ValueError, match="hop_s"):
        confirm_windows_for(0.0)
