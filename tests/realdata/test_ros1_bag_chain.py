"""The real ROS 1 bag (robot_localization test1.bag, a Clearpath Husky) through the chain:
ingest with the Husky topic map -> 5-s chunks -> 1.7-s windows -> side-channel features.

Ground truth: the bag's SOURCE.md (topics, message counts, 395 s, IMU mounted with gravity on
sensor +y) and the physics of a skid-steer robot (gyro yaw rate ~ (vR - vL)/B on firm ground).
"""

from pathlib import Path

import numpy as np
import pytest

from terrainml.robot import load_robot

BAG = Path(__file__).resolve().parents[2].parent / "shared" / "datasets" / "robot_localization_husky" / "test1.bag"
pytestmark = pytest.mark.skipif(not BAG.is_file(), reason=f"{BAG} not present")

NO_CURRENT = {k: v for k, v in {
    "imu_ax": "imu_ax_mps2", "imu_ay": "imu_ay_mps2", "imu_az": "imu_az_mps2",
    "imu_wz": "imu_yaw_rate_radps", "speed_left_mps": "wheel1_omega_radps",
    "speed_right_mps": "wheel2_omega_radps"}.items()}


@pytest.fixture(scope="module")
def bag_run():
    from terrainml.io.ingest import load_run

    return load_run(BAG, robot=load_robot("husky"), topic_map="husky_robot_localization")


def test_bag_ingests_with_expected_topics_and_duration(bag_run):
    rep = bag_run.report
    assert rep.usable and rep.format == "bag" and not rep.errors
    # SOURCE.md: /imu/data 11,865, odometry 3,952, /fix 989 (not mapped: skipped, counted)
    assert rep.topics["/imu/data"]["decoded"] == 11865
    assert rep.topics["/husky_velocity_controller/odom"]["decoded"] == 3952
    assert rep.topics["/fix"]["read"] == 989 and rep.topics["/fix"]["decoded"] == 0
    assert rep.span_s == pytest.approx(395.0, abs=1.0)
    t = bag_run.table
    assert t["run_id"].iloc[0] == "test1"
    assert not t["current_valid"].any() and not t["cam_valid"].any()  # no currents, no camera


def test_bag_windows_and_features(bag_run):
    from terrainml.experiments.borealtc import chunk_windows, make_chunks
    from terrainml.features.side_channel import side_channel_features

    t = bag_run.table.copy()
    t["terrain"] = 0  # unlabelled log: a single dummy class to reuse the chunker
    chunks = make_chunks([t], chunk_s=5.0, valid_cols=("imu_valid", "wheels_valid"))
    # 395 s -> at most 79 chunks; the few invalid ticks cost at most a handful
    assert 70 <= len(chunks) <= 79
    w = chunk_windows([t], chunks, window_s=1.7, max_windows_per_chunk=2, channels=NO_CURRENT,
                      wheel_radius_m=0.1651)
    assert w.X.shape[1:] == (6, 170) and np.isfinite(w.X).all()
    F, names = side_channel_features(w.X, w.channels, 100.0, track_m=0.5708)
    f = {n: F[:, k] for k, n in enumerate(names)}
    assert np.isfinite(F).all()
    # gravity on body +z after the mount rotation from the Husky spec
    assert np.median(f["imu_az__mean"]) == pytest.approx(9.8, abs=0.2)
    # outdoor drive at about 1 m/s
    assert 0.5 < np.median(f["speed__forward_mean"]) < 1.5
    # skid-steer: gyro yaw rate follows the wheel-speed yaw rate, so the windows' gyro and
    # kinematic yaw rates are strongly correlated
    wz = f["imu_wz__mean"]
    wkin = f["speed_lr__diff_mean"] / 0.5708
    assert np.corrcoef(wz, wkin)[0, 1] > 0.8
