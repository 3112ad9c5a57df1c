"""Kinematic tracked robots on a patch map (terrainml.sim.tracked, terrainml.sim.patch_slip).

Expected values are worked by hand from the model's equations (module docstrings), not from the code.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from terrainml.sim.patch_slip import PatchGrid, PatchSlipModel
from terrainml.sim.tracked import TrackedFleet, TrackedNoise, track_geometry, tracked_robot

QUIET = TrackedNoise(process_noise_mps=0.0, encoder_noise_radps=0.0, vel_noise_mps=0.0,
                     yaw_rate_noise_radps=0.0, outlier_fraction=0.0, outlier_mps=0.0)


def test_grid_numbers_patches_row_major_and_clamps_outside():
    g = PatchGrid(9.0, 3.0)
    assert (g.n_side, g.n_patches) == (3, 9)
    xy = np.array([[0.5, 0.5], [4.0, 0.1], [8.9, 4.0], [1.0, 7.0], [-2.0, 20.0]])
    np.testing.assert_array_equal(g.index(xy), [0, 1, 5, 6, 6])
    assert g.key(5) == "r1c2" and list(g.keys()[[0, 8]]) == ["r0c0", "r2c2"]


def test_straight_drive_loses_the_traction_slip():
    # one patch, s1 = 0.2; both sprockets at 10 rad/s with R = 0.1 m: v_i = 1 m/s, no turn, so
    # beta_i = 0.2 * 1 * (0.5 + 0.5) = 0.2 m/s and the ground speed is 0.8 m/s.
    terrain = PatchSlipModel.from_s1([4], [0.2])
    fleet = TrackedFleet(terrain, PatchGrid(3.0, 3.0), 0.1, 0.6, [[0.5, 1.5]], [0.0], 0.05, QUIET, seed=0)
    for _ in range(20):
        m = fleet.step(np.array([10.0]), np.array([10.0]))
    assert m.vx_mps[0] == pytest.approx(0.8) and m.vy_mps[0] == pytest.approx(0.0)
    assert m.yaw_rate_radps[0] == pytest.approx(0.0)
    assert m.omega_l_radps[0] == 10.0  # quiet encoders read the set-point
    np.testing.assert_allclose(fleet.xy_m[0], [0.5 + 20 * 0.05 * 0.8, 1.5])


def test_turn_on_slip_free_ground_still_skids():
    # s1 = 0: c_turn = 0.1, alpha_max = 0.03 rad. v_L = 0.5, v_R = 1.5 m/s (R = 0.1 m, B = 0.5 m):
    # d = 1, turn = 0.1 * 0.5 * 1 * (1 + 0.2) = 0.06 m/s; tracks 0.56 and 1.44 m/s on the ground,
    # v_x = 1.0 m/s, yaw rate 0.88 / 0.5 = 1.76 rad/s (kinematics says 2.0);
    # alpha = -0.03 tanh(1.0 * (1 / 0.5) / 0.3), v_y = v_x tan(alpha).
    terrain = PatchSlipModel.from_s1([0], [0.0])
    fleet = TrackedFleet(terrain, PatchGrid(3.0, 3.0), 0.1, 0.5, [[1.0, 1.0]], [0.0], 0.01, QUIET, seed=0)
    m = fleet.step(np.array([5.0]), np.array([15.0]))
    alpha = -0.03 * math.tanh(2.0 / 0.3)
    assert m.vx_mps[0] == pytest.approx(1.0)
    assert m.yaw_rate_radps[0] == pytest.approx(1.76)
    assert m.vy_mps[0] == pytest.approx(math.tan(alpha))
    assert fleet.yaw_rad[0] == pytest.approx(0.0176)
    np.testing.assert_allclose(fleet.xy_m[0], [1.01, 1.0 + 0.01 * math.tan(alpha)])


def test_same_seed_same_measurements_and_outlier_share():
    terrain = PatchSlipModel.from_s1([2], [0.125])
    noise = TrackedNoise(outlier_fraction=0.25, outlier_mps=5.0, vel_noise_mps=0.0)
    runs = []
    for _ in range(2):
        fleet = TrackedFleet(terrain, PatchGrid(3.0, 3.0), 0.1, 0.6, np.full((400, 2), 1.5), np.zeros(400),
                             0.05, noise, seed=np.random.SeedSequence(7))
        runs.append(fleet.step(np.full(400, 5.0), np.full(400, 5.0)).vx_mps)
    np.testing.assert_array_equal(runs[0], runs[1])
    glitched = np.abs(runs[0] - np.median(runs[0])) > 0.1
    assert 0.15 < glitched.mean() < 0.30  # 25 % outliers, most of them larger than 0.1 m/s


def test_tracked_robot_geometry():
    radius_m, track_m = track_geometry(tracked_robot())
    assert radius_m == pytest.approx(0.0856) and track_m == pytest.approx(0.60)
