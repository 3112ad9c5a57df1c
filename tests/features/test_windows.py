"""Steady-window rules, channels, and offline/online parity (design §8)."""

from __future__ import annotations

import numpy as np
import pytest

from terrainml.features.sets import FeatureSet
from terrainml.features.windows import WindowSpec, cut_windows
from terrainml.robot import load_robot

from est_synth import make_est


def test_steady_run_keeps_every_window_with_exact_means():
    est = make_est(n=1000, speed_mps=0.8, slip=0.12, current_a=4.0)
    wins, counts = cut_windows(est, load_robot("agrimaro"))
    assert counts["n_windows"] == 5 and counts["n_kept"] == 5 and counts["n_rejected"] == 0
    assert wins.X.shape == (5, 12, 200)
    assert wins.channels == ("slip_1", "slip_2", "slip_3", "current_1", "current_2", "current_3",
                             "vx", "vy", "r", "imu_ax", "imu_ay", "imu_az")
    # window 3 holds rows 600..799 exactly
    k = wins.channels.index("current_2")
    np.testing.assert_array_equal(wins.X[3, k], est["wheel2_current_a"].to_numpy()[600:800])
    assert wins.meta["start_index"].tolist() == [0, 200, 400, 600, 800]
    assert wins.meta["t_start_s"].iloc[1] == pytest.approx(2.0)
    assert set(wins.meta["terrain"]) == {2} and set(wins.meta["run_id"]) == {"run_a"}


def test_each_rule_rejects_its_window_and_is_counted():
    est = make_est(n=2000)
    n = len(est)
    sl = lambda w: slice(200 * w, 200 * (w + 1))  # noqa: E731
    est.loc[est.index[sl(0)][:30], "state2"] = "traction"        # 15% traction -> wheel_state
    est.loc[est.index[sl(1)], "ekf_vx_mps"] = 0.1                 # slow -> speed
    est.loc[est.index[sl(2)], "ekf_ax_mps2"] = 0.3                # accelerating -> acceleration
    est.loc[est.index[sl(3)], "ekf_steer1_rad"] = 0.1 * np.sin(np.arange(200) / 10)  # steering
    est.loc[est.index[sl(4)][100:], "terrain"] = 3                # label change -> terrain_label
    est.loc[est.index[sl(5)][:20], "imu_valid"] = False           # 10% invalid -> channel_valid
    t = est["t_s"].to_numpy().copy()
    t[1250:] += 0.05                                              # a 5-tick gap inside window 6
    est["t_s"] = t
    wins, counts = cut_windows(est, load_robot("agrimaro"))
    assert counts["n_windows"] == 10
    for rule in ("wheel_state", "speed", "acceleration", "steering", "terrain_label",
                 "channel_valid", "time_gap"):
        assert counts[rule] == 1, (rule, counts)
    assert counts["n_rejected"] == 7 and counts["n_kept"] == 3
    assert wins.meta["start_index"].tolist() == [1400, 1600, 1800]
    assert n == 2000


def test_tolerated_invalid_samples_are_interpolated():
    est = make_est(n=200, current_a=5.0)
    est.loc[10:14, "wheel1_current_a"] = np.nan  # 2.5% < 5%: kept
    est["wheel1_current_a"] = est["wheel1_current_a"].where(est.index.to_series().sub(12).abs() > 2,
                                                            np.nan)
    wins, counts = cut_windows(est, load_robot("agrimaro"))
    assert counts["n_kept"] == 1
    x = wins.X[0, wins.channels.index("current_1")]
    assert np.isfinite(x).all()
    a, b = est["wheel1_current_a"].iloc[9], est["wheel1_current_a"].iloc[15]
    assert x[12] == pytest.approx(a + (b - a) * 3 / 6)


def test_robot_without_camera_has_no_slip_channels():
    husky = load_robot("husky")
    est = make_est(n=400, n_wheels=4)
    for i in range(1, 5):
        est[f"slip{i}"] = np.nan
    est["slip_available"] = False
    wins, counts = cut_windows(est, husky)
    assert counts["n_kept"] == 2
    assert wins.channels == ("current_1", "current_2", "current_3", "current_4", "vx", "vy", "r",
                             "imu_ax", "imu_ay", "imu_az")
    F = FeatureSet.for_robot(husky).fit_transform(wins)
    assert np.isfinite(F).all()


def test_restricted_channels_and_unknown_channel():
    est = make_est(n=200)
    spec = WindowSpec(channels=("current_1", "vx"))
    wins, _ = cut_windows(est, load_robot("agrimaro"), spec)
    assert wins.X.shape == (1, 2, 200)
    with pytest.raises(ValueError, match="unknown window channel"):
        cut_windows(est, load_robot("agrimaro"), WindowSpec(channels=("torque_1",)))


def test_online_cut_of_one_buffer_is_the_latest_window():
    est = make_est(n=450)
    wins, counts = cut_windows(est, load_robot("agrimaro"), online=True)
    # ends at the last row, hop 0.5 s backwards: starts 250, 200, ..., 0 -> 6 windows
    assert wins.meta["start_index"].tolist() == [0, 50, 100, 150, 200, 250]
    one, _ = cut_windows(est.iloc[-200:].reset_index(drop=True), load_robot("agrimaro"), online=True)
    assert len(one) == 1
    np.testing.assert_array_equal(one.X[0], wins.X[-1])


def test_ring_buffer_layout_bools_as_floats_no_labels_gives_the_same_window():
    """The stream's ring buffer stores flags as floats and has no label: same window, label -1."""
    est = make_est(n=200)
    buf = est.drop(columns=["terrain", "run_id"]).copy()
    for c in buf.columns:
        if buf[c].dtype == bool:
            buf[c] = buf[c].astype(float)
    a, _ = cut_windows(est, load_robot("agrimaro"), online=True)
    b, _ = cut_windows(buf, load_robot("agrimaro"), online=True)
    np.testing.assert_array_equal(a.X, b.X)
    assert b.meta["terrain"].tolist() == [-1]
    buf.loc[:15, "imu_valid"] = 0.0  # 8% invalid -> rejected
    c, counts = cut_windows(buf, load_robot("agrimaro"), online=True)
    assert len(c) == 0 and counts["channel_valid"] == 1
