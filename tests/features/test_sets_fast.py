"""The vectorised feature code against independent references: the plain per-channel
transcription (``reference_features``, scipy.signal.welch + np.percentile) and scipy's Welch
estimate itself; single window vs batch; selected-columns path vs all columns."""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd
import pytest
from scipy.signal import welch

from terrainml.features.sets import FeatureSet, compute_features, feature_names, traction_sense
from terrainml.features.windows import Windows, cut_windows
from terrainml.robot import load_robot

from est_synth import make_est
from reference_features import reference_features
from reference_features import traction_sense as reference_traction_sense

CH = ("slip_1", "slip_2", "slip_3", "current_1", "current_2", "current_3", "vx", "vy", "r",
      "imu_ax", "imu_ay", "imu_az")
ROBOT = load_robot("agrimaro")
KW = dict(rate_hz=100.0, torque_constant_nm_per_a=ROBOT.torque_constant_nm_per_a,
          wheel_radius_m=ROBOT.wheel_radius_m, wheel_loads_n=tuple(ROBOT.static_wheel_loads_n()))


def _assert_same(F, R, rtol=1e-9):
    """Equal to rtol relative, NaN where the reference has NaN; a column's absolute floor is
    1e-12 of its largest value (a mean of +-x over wheels, a spread of equal numbers: ~0)."""
    assert F.shape == R.shape
    np.testing.assert_array_equal(np.isnan(F), np.isnan(R))
    scale = np.nanmax(np.where(np.isfinite(R), np.abs(R), 0.0), axis=0, initial=0.0)
    with np.errstate(invalid="ignore"):  # inf - inf where both are inf (then F == R)
        ok = np.isnan(R) | (F == R) | (np.abs(F - R) <= rtol * np.abs(R) + 1e-12 * scale)
    bad = np.argwhere(~ok)
    assert not bad.size, f"{len(bad)} values differ, first at {bad[0]}: {F[tuple(bad[0])]} vs {R[tuple(bad[0])]}"


def _pipeline_windows() -> Windows:
    """Windows cut by the real window code from steady runs: forward, driven backwards
    (negative currents: the traction sense flips slip and current), near-zero slip."""
    wins = []
    for k, (v, s, i) in enumerate([(0.8, 0.12, 4.0), (1.3, 0.3, -3.0), (0.6, 0.004, 1.5)]):
        est = make_est(n=800, speed_mps=v, slip=s, current_a=i, seed=k, run_id=f"r{k}")
        w, _ = cut_windows(est, load_robot("agrimaro"))
        wins.append(w)
    X = np.concatenate([w.X for w in wins])
    meta = pd.concat([w.meta for w in wins], ignore_index=True)
    return Windows(X, wins[0].channels, meta)


def _structured_windows(n: int, T: int, seed: int) -> np.ndarray:
    """Random windows with the structure of real ones: offsets, tones, coloured noise,
    mixed-sign currents, a constant channel, exact zeros."""
    rng = np.random.default_rng(seed)
    t = np.arange(T) / 100.0
    X = np.empty((n, len(CH), T))
    for k in range(n):
        for c in range(len(CH)):
            f = rng.uniform(0.5, 45.0)
            noise = np.cumsum(rng.standard_normal(T)) * rng.uniform(0.0, 0.05)
            X[k, c] = (rng.normal(0, 3) + rng.uniform(0, 2) * np.sin(2 * np.pi * f * t + rng.uniform(0, 6))
                       + noise + rng.uniform(0.01, 1.0) * rng.standard_normal(T))
        X[k, CH.index("imu_az")] += 9.81
    X[0, CH.index("vy")] = 0.25          # constant: skew/kurtosis 0, flat spectrum
    X[1, CH.index("current_2")] = 0.0    # exactly zero current: sign kept, zero spectrum
    X[2, CH.index("current_1")] -= 50.0  # strongly negative: flipped
    return X


def test_pipeline_windows_equal_the_reference():
    w = _pipeline_windows()
    assert len(w) >= 9
    F, names = compute_features(w.X, w.channels, **KW)
    R, rnames = reference_features(w.X, w.channels, **KW)
    assert names == rnames
    _assert_same(F, R)
    # the backwards run really exercised the traction sense
    k = names.index("current_1__mean")
    assert (R[:, k] > 0).all() and (w.X[:, w.channels.index("current_1")].mean(axis=1) < 0).any()


@pytest.mark.parametrize("T", [200, 129, 64, 300])
def test_structured_windows_of_several_lengths_equal_the_reference(T):
    X = _structured_windows(6, T, seed=T)
    F, names = compute_features(X, CH, **KW)
    R, rnames = reference_features(X, CH, **KW)
    assert names == rnames
    _assert_same(F, R)


@pytest.mark.parametrize("T", [200, 128, 100, 257, 9])
def test_band_powers_and_centroid_equal_scipy_welch(T):
    rng = np.random.default_rng(T)
    t = np.arange(T) / 100.0
    X = np.zeros((3, len(CH), T))
    az = CH.index("imu_az")
    for k in range(3):
        X[k, az] = 9.81 + np.sin(2 * np.pi * (3 + 11 * k) * t) + 0.2 * rng.standard_normal(T)
    F, names = compute_features(X, CH)
    f, P = welch(X[:, az], fs=100.0, nperseg=min(128, T), detrend="constant")
    df = f[1] - f[0]
    for lo, hi in ((0, 5), (5, 15), (15, 30), (30, 50)):
        sel = (f >= lo) & ((f <= hi) if hi == 50 else (f < hi))
        ref = np.log10(P[:, sel].sum(axis=1) * df + 1e-12)
        np.testing.assert_allclose(F[:, names.index(f"imu_az__bp_{lo}_{hi}hz")], ref, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(F[:, names.index("imu_az__centroid_hz")], (P * f).sum(1) / P.sum(1),
                               rtol=1e-10)


def test_one_window_at_a_time_equals_the_batch():
    X = np.concatenate([_pipeline_windows().X, _structured_windows(4, 200, seed=1)])
    F, _ = compute_features(X, CH, **KW)
    for k in range(len(X)):
        np.testing.assert_allclose(compute_features(X[k:k + 1], CH, **KW)[0], F[k:k + 1], rtol=1e-12, atol=1e-15)


def test_selected_columns_equal_the_full_transform():
    X = np.concatenate([_pipeline_windows().X, _structured_windows(3, 200, seed=2)])
    w = Windows(X, CH, None)
    fs = FeatureSet.for_robot(ROBOT).fit(w)
    full = fs.transform(w)
    names = list(fs.get_feature_names_out())
    rng = np.random.default_rng(0)
    subsets = [np.arange(len(names))] + [np.sort(rng.choice(len(names), size=s, replace=False))
                                         for s in (1, 5, 40, 120)]
    # every column alone (each family's own dependencies, nothing else computed)
    subsets += [np.array([k]) for k in range(len(names))]
    for cols in subsets:
        np.testing.assert_allclose(fs._transform_columns(w, cols), full[:, cols], rtol=1e-12, atol=1e-15)
    # a named subset's FeatureSet (its _keep) takes the same path
    cur = FeatureSet.for_robot(ROBOT, subset="currents").fit(w)
    cn = list(cur.get_feature_names_out())
    np.testing.assert_allclose(cur._transform_columns(w, np.array([3, 7])),
                               full[:, [names.index(cn[3]), names.index(cn[7])]], rtol=1e-12)


def test_non_finite_samples_propagate_as_in_the_reference():
    X = _structured_windows(3, 200, seed=3)
    X[0, CH.index("current_2"), 17] = np.nan   # spectral channel, and its wheel's slip is flipped by nanmean
    X[1, CH.index("imu_ax"), 5] = np.inf
    X[2, CH.index("slip_1"), :] = np.nan        # all-NaN slip
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # nanmean of the all-NaN slip
        R, _ = reference_features(X, CH, **KW)
        F, _ = compute_features(X, CH, **KW)
    _assert_same(F, R)
    assert np.isnan(F).any()


@pytest.mark.parametrize("channels", [
    ("current_1", "current_2", "imu_az"),                          # no slip, no body speed
    ("slip_2", "current_1", "current_2", "vx", "vy", "imu_az"),    # the first wheel has no slip
    ("imu_ax", "imu_ay", "imu_az", "vx", "vy"),                    # no wheels at all
    ("vx", "vy", "r", "slip_1", "slip_2", "current_2", "current_1", "imu_ax"),  # other order, no imu_az
])
def test_other_channel_sets_equal_the_reference(channels):
    rng = np.random.default_rng(len(channels))
    X = rng.standard_normal((4, len(channels), 200)) + rng.normal(0, 2, (4, len(channels), 1))
    F, names = compute_features(X, channels, **KW)
    R, rnames = reference_features(X, channels, **KW)
    assert names == rnames == feature_names(channels, 200)
    _assert_same(F, R)


def test_traction_sense_equals_the_reference_and_rejects_duplicate_channels():
    X = _structured_windows(4, 200, seed=4)
    np.testing.assert_array_equal(traction_sense(X, CH), reference_traction_sense(X, CH))
    with pytest.raises(ValueError, match="duplicate"):
        compute_features(X[:, :3], ("slip_1", "slip_1", "current_1"))
