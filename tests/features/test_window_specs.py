"""Named window specs (design §8): registry, side channels, the state spec's rule."""

import numpy as np
import pandas as pd
import pytest

from terrainml.features.windows import (RULES, WINDOW_SPECS, WindowSpec, channel_column, cut_windows,
                                        window_spec)
from terrainml.pipeline.dataset import sensors_of
from terrainml.robot import load_robot


def test_named_specs_exist_and_round_trip():
    for name in ("steady", "chunks", "state"):
        assert name in WINDOW_SPECS
        spec = window_spec(name)
        assert spec.name == name
        assert WindowSpec.from_dict(spec.to_dict()) == spec
    assert window_spec("steady") == WindowSpec()  # the default is the design's steady rules
    chunks = window_spec("chunks")
    assert chunks.n_samples == 170 and chunks.chunk_s == 5.0  # the BorealTC authors' 1.7 s in 5 s
    with pytest.raises(ValueError, match="unknown window spec"):
        window_spec("nope")
    with pytest.raises(ValueError, match="unknown rule"):
        WindowSpec(rules=("speed", "no_such_rule"))


def test_side_channels_map_to_the_robots_left_and_right_wheels():
    husky = load_robot("husky")  # wheel 1 front-left (y > 0), wheel 2 front-right
    assert channel_column("current_left", husky)[0] == "wheel1_current_a"
    col, valid, scale = channel_column("speed_right_mps", husky)
    assert col == "wheel2_omega_radps" and valid == ("wheels_valid",)
    assert scale == pytest.approx(husky.wheel_radius_m)
    assert channel_column("imu_wx", husky)[0] == "imu_roll_rate_radps"


def test_sensor_subsets_restrict_channels():
    husky = load_robot("husky")
    chans = window_spec("chunks").channels_for(husky, ["wheels", "currents"])
    assert chans == ("current_left", "current_right", "speed_left_mps", "speed_right_mps")
    assert sensors_of(chans) == ["wheels", "currents"]
    assert sensors_of(window_spec("chunks").channels_for(husky)) == ["wheels", "currents", "imu"]
    with pytest.raises(ValueError, match="unknown sensor group"):
        window_spec("chunks").channels_for(husky, ["wheels", "lidar"])


def test_body_channels_need_the_camera_of_a_robot_that_has_one():
    """The EKF's body velocity is camera-aided on a robot with a camera: a subset without the
    camera drops it (the velocity would be wheel odometry at serving); without a camera the
    body channels are odometry in training and serving alike, and stay."""
    ref, husky = load_robot("agrimaro"), load_robot("husky")
    assert ref.has_camera and not husky.has_camera
    short = window_spec("short")
    assert short.channels_for(ref, ["wheels", "currents", "imu"]) == (
        "current_1", "current_2", "current_3", "imu_ax", "imu_ay", "imu_az")
    assert {"vx", "vy", "r", "slip_1"} <= set(short.channels_for(ref, ["wheels", "imu", "cam"]))
    assert short.channels_for(husky, ["wheels", "currents"])[-3:] == ("vx", "vy", "r")


def _est(states, n=200, speed=1.0, ax=0.0):
    """An EST table of n ticks at 100 Hz, wheel states given per wheel (list of n strings each)."""
    t = np.arange(n) / 100.0
    df = pd.DataFrame({"t_s": t, "ekf_vx_mps": speed, "ekf_vy_mps": 0.0, "ekf_yaw_rate_radps": 0.0,
                       "ekf_ax_mps2": ax, "ekf_ay_mps2": 0.0, "terrain": 2, "run_id": "r"})
    for i in range(1, 5):
        df[f"state{i}"] = states
        df[f"wheel{i}_current_a"] = 1.0
        df[f"slip{i}"] = 0.1
    for c in ("imu_ax_mps2", "imu_ay_mps2", "imu_az_mps2"):
        df[c] = 0.0
    return df


def test_state_spec_keeps_an_accelerating_window_the_steady_rules_reject():
    robot = load_robot(None)
    est = _est(["traction"] * 200, ax=0.5)  # accelerating hard, every wheel in traction
    _, steady = cut_windows(est, robot, window_spec("steady"))
    assert steady["n_kept"] == 0 and steady["wheel_state"] == 1 and steady["acceleration"] == 1
    wins, state = cut_windows(est, robot, window_spec("state"))
    assert state["n_kept"] == 1 and len(wins) == 1
    assert state["acceleration"] == 0  # not a rule of this spec: never counted
    # a window that switches state half-way is not conditioned on one state
    mixed = _est(["traction"] * 100 + ["braking"] * 100)
    assert cut_windows(mixed, robot, window_spec("state"))[1]["wheel_state"] == 1
    assert set(window_spec("state").active_rules) < set(RULES)


def test_label_at_end_keeps_a_straddling_window_with_the_newest_terrain():
    """A window across a terrain change is labelled with the terrain under the robot
    when it ends (what serving must report); ``only`` (every other spec) rejects it."""
    robot = load_robot(None)
    est = _est(["steady"] * 100, n=100)
    est["terrain"] = [3] * 70 + [-1] * 5 + [5] * 25  # 3 then 5, a few unlabelled rows between
    spec = window_spec("short", label_at="only")  # 1 s windows: one window over the 100 ticks
    _, counts = cut_windows(est, robot, spec)
    assert counts["n_kept"] == 0 and counts["terrain_label"] == 1
    assert window_spec("short").label_at == "end" and window_spec("steady").label_at == "only"
    wins, counts = cut_windows(est, robot, window_spec("short"))
    assert counts["n_kept"] == 1 and counts["terrain_label"] == 0
    assert wins.meta["terrain"].tolist() == [5]
    est["terrain"] = [5] * 90 + [3] * 8 + [-1] * 2  # newest LABELLED row decides, not the last row
    assert cut_windows(est, robot, window_spec("short", label_at="end"))[0].meta["terrain"].tolist() == [3]
    # a homogeneous window keeps its one label; the field round-trips, and the default is left
    # out of the dict so specs made before it existed keep their keys
    est["terrain"] = 4
    assert cut_windows(est, robot, window_spec("short", label_at="end"))[0].meta["terrain"].tolist() == [4]
    end = window_spec("short", label_at="end")
    assert WindowSpec.from_dict(end.to_dict()) == end
    assert "label_at" not in window_spec("steady").to_dict()
    with pytest.raises(ValueError, match="label_at"):
        WindowSpec(label_at="start")


def test_the_track_is_the_spread_of_the_wheels_lateral_positions():
    from terrainml.features.side_channel import track_of
    from terrainml.robot import load_robot

    assert track_of(load_robot("husky")) == pytest.approx(2 * 0.2854)  # wheels at y = +-0.2854 m
    # the reference robot: two wheels on the centre line (y = 0) and one at y = -0.756 m; the
    # first two wheels' distance would be 0 and the yaw residual a division by zero
    assert track_of(load_robot("agrimaro")) == pytest.approx(0.756)
