"""Feature values against hand-computed truth (design §8)."""

from __future__ import annotations

import numpy as np
import pytest

from terrainml.features.sets import FEATURE_SUBSETS, FeatureSet, compute_features
from terrainml.features.windows import Windows
from terrainml.robot import load_robot

CH = ("slip_1", "slip_2", "slip_3", "current_1", "current_2", "current_3", "vx", "vy", "r",
      "imu_ax", "imu_ay", "imu_az")


def _windows(n=4, seed=0):
    rng = np.random.default_rng(seed)
    X = rng.standard_normal((n, len(CH), 200))
    import pandas as pd

    meta = pd.DataFrame({"run_id": ["a"] * n, "terrain": [0] * n, "t_start_s": 0.0, "t_end_s": 1.99,
                         "start_index": range(n)})
    return Windows(X, CH, meta)


def _feat(F, names, name):
    return F[:, names.index(name)]


def test_statistics_of_a_known_signal():
    X = np.zeros((1, len(CH), 200))
    X[0, CH.index("vx")] = np.arange(200, dtype=float)  # 0..199: mean 99.5, population std sqrt((200^2-1)/12)
    F, names = compute_features(X, CH)
    assert _feat(F, names, "vx__mean")[0] == pytest.approx(99.5)
    assert _feat(F, names, "vx__std")[0] == pytest.approx(np.sqrt((200 ** 2 - 1) / 12))
    assert _feat(F, names, "vx__min")[0] == 0 and _feat(F, names, "vx__max")[0] == 199
    assert _feat(F, names, "vx__p50")[0] == pytest.approx(99.5)
    assert _feat(F, names, "vx__skew")[0] == pytest.approx(0.0, abs=1e-12)
    assert _feat(F, names, "vx__kurtosis")[0] == pytest.approx(-1.2, abs=1e-3)  # uniform: -6/5
    assert _feat(F, names, "vy__skew")[0] == 0.0 and _feat(F, names, "vy__kurtosis")[0] == 0.0  # constant


def test_spectral_band_and_centroid_of_a_sinusoid():
    t = np.arange(200) / 100.0
    X = np.zeros((1, len(CH), 200))
    X[0, CH.index("imu_az")] = 9.81 + np.sin(2 * np.pi * 10.0 * t)
    F, names = compute_features(X, CH)
    bands = {b: _feat(F, names, f"imu_az__{b}")[0] for b in ("bp_0_5hz", "bp_5_15hz", "bp_15_30hz", "bp_30_50hz")}
    assert max(bands, key=bands.get) == "bp_5_15hz"
    assert 10 ** bands["bp_5_15hz"] == pytest.approx(0.5, rel=0.1)  # mean square of a unit sine
    assert _feat(F, names, "imu_az__centroid_hz")[0] == pytest.approx(10.0, abs=1.0)


def test_physics_features():
    robot = load_robot("agrimaro")
    loads = robot.static_wheel_loads_n()
    X = np.zeros((1, len(CH), 200))
    rng = np.random.default_rng(1)
    s = 0.1 + 0.01 * rng.standard_normal(200)
    X[0, CH.index("slip_2")] = s
    X[0, CH.index("current_2")] = 4.0 + 30.0 * (s - s.mean())  # exactly 30 A per unit slip
    X[0, CH.index("vx")] = 0.8
    fs = FeatureSet.for_robot(robot).fit(Windows(X, CH, None))
    F = fs.transform(X)
    names = list(fs.get_feature_names_out())
    assert _feat(F, names, "current_2__traction_effort")[0] == pytest.approx(
        robot.torque_constant_nm_per_a * 4.0 / (robot.wheel_radius_m * loads[1]))
    assert _feat(F, names, "current_2__per_speed")[0] == pytest.approx(4.0 / 0.8)
    var = s.var()
    assert _feat(F, names, "current_2__slip_slope")[0] == pytest.approx(30.0 * var / (var + 1e-6))
    assert _feat(F, names, "slip_wheels__mean")[0] == pytest.approx(s.mean() / 3)


def test_wheel_order_invariant_aggregates():
    w = _windows()
    perm = [2, 0, 1, 5, 3, 4, 6, 7, 8, 9, 10, 11]  # swap wheel roles (slip and current together)
    F1, names = compute_features(w.X, CH)
    F2, _ = compute_features(w.X[:, perm], CH)
    agg = [k for k, n in enumerate(names) if "_wheels__" in n and "traction_effort" not in n]
    assert len(agg) > 50
    np.testing.assert_allclose(F1[:, agg], F2[:, agg], rtol=1e-12, atol=1e-12)


def test_subsets_partition_all_and_names_match_columns():
    w = _windows()
    all_fs = FeatureSet(subset="all").fit(w)
    names_all = set(all_fs.get_feature_names_out())
    parts = {s: set(FeatureSet(subset=s).fit(w).get_feature_names_out()) for s in FEATURE_SUBSETS[:-1]}
    assert set().union(*parts.values()) == names_all
    assert sum(len(p) for p in parts.values()) == len(names_all)
    assert all(n.startswith("imu") for n in parts["imu"])
    assert not any(n.startswith(("imu", "current")) for n in parts["kinematic"])
    assert all_fs.transform(w).shape == (4, len(names_all))


def test_transform_reorders_windows_channels_and_rejects_wrong_input():
    w = _windows()
    fs = FeatureSet().fit(w)
    shuffled = w.select_channels(list(reversed(CH)))
    np.testing.assert_array_equal(fs.transform(shuffled), fs.transform(w))
    with pytest.raises(ValueError, match="channel_names"):
        FeatureSet().fit(w.X)
    with pytest.raises(ValueError, match="subset"):
        FeatureSet(subset="bogus").fit(w)
