"""Topic-map kind ``body_odometry``: a REP 105 odometry as the body-velocity reference."""

import math

import numpy as np
import pytest

from terrainml.io.ingest.signals import SourceFacts, signals_for
from terrainml.io.topicmap import load_topic_map
from terrainml.robot import load_robot


def test_body_twist_and_odom_yaw_become_the_camera_columns():
    tmap = load_topic_map("husky_ros2")
    src = tmap.by_topic()["/odometry/filtered"]
    half = math.pi / 4                     # yaw 90 degrees
    part = {"t_ns": np.array([0, 10_000_000]), "position": np.zeros((2, 3)),
            "orientation": np.array([[0.0, 0.0, math.sin(half), math.cos(half)]] * 2),
            "linear": np.array([[0.7, -0.1, 0.0], [0.8, 0.0, 0.0]]), "angular": np.array([[0, 0, 0.2], [0, 0, 0.3]]),
            "cov0": np.zeros(2)}
    sig = {s.column: s for s in signals_for(src, part, np.array([0.0, 0.01]), load_robot("husky"), tmap,
                                            SourceFacts(gap_s=0.02))}
    assert sig["cam_vx_mps"].values.tolist() == [0.7, 0.8]
    assert sig["cam_vy_mps"].values.tolist() == [-0.1, 0.0]
    assert sig["cam_yaw_rate_radps"].values.tolist() == [0.2, 0.3]
    assert sig["cam_yaw_rad"].values == pytest.approx([math.pi / 2] * 2)
    assert sig["cam_yaw_rad"].method == "angle"
