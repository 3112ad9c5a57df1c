"""Hand-worked T265 frame cases (thesis §5.2.3, eq. 5.1-5.10)."""

import numpy as np
import pytest

from terrainml.io import t265
from terrainml.robot import load_robot

MOUNT = (0.6685, -0.26875, 0.0)  # thesis §5.2.3


def test_forward_translation_in_pose_axes_is_plus_x_body():
    # camera not rotated; moving forward = along -z of the T265 pose frame (z points backward)
    out = t265.t265_odometry_to_body([[0, 0, -1.0]], [[0, 0, 0, 1.0]], [[0, 0, -0.8]], [[0, 0, 0]])
    assert out["vx_mps"][0] == pytest.approx(0.8)
    assert out["vy_mps"][0] == pytest.approx(0.0, abs=1e-12)
    # moving right (+x pose) is -y body; up (+y pose) is +z body
    out = t265.t265_odometry_to_body([[0, 0, 0]], [[0, 0, 0, 1.0]], [[0.5, 0.3, 0]], [[0, 0, 0]])
    assert out["vy_mps"][0] == pytest.approx(-0.5)
    assert out["vz_mps"][0] == pytest.approx(0.3)


def test_world_velocity_rotated_into_camera_frame():
    # camera yawed +90 deg (left) since power-on: it now faces the old "left" = -x of t265_odom.
    # Driving forward, its velocity in t265_odom axes is (-1, 0, 0); body vx must be +1.
    yaw = np.pi / 2
    # yaw about body z is rotation about +y of the pose frame (y up)
    q = np.array([0.0, np.sin(yaw / 2), 0.0, np.cos(yaw / 2)])
    out = t265.t265_odometry_to_body([[0, 0, 0]], [q], [[-1.0, 0, 0]], [[0, 0.2, 0]])
    assert out["vx_mps"][0] == pytest.approx(1.0)
    assert out["vy_mps"][0] == pytest.approx(0.0, abs=1e-12)
    assert out["yaw_raw_rad"][0] == pytest.approx(np.pi / 2)
    assert out["yaw_rate_radps"][0] == pytest.approx(0.2)


def test_in_place_yaw_gives_zero_robot_velocity_after_lever_arm():
    # robot spins in place at 1 rad/s: the mount moves on a circle, v_mount = w x d
    t = np.linspace(0, 3, 31)
    msg = t265.body_to_t265_odometry(np.zeros_like(t), np.zeros_like(t), t * 1.0, np.zeros_like(t),
                                     np.zeros_like(t), np.ones_like(t), MOUNT)
    out = t265.t265_odometry_to_body(msg["position_m"], msg["orientation_xyzw"], msg["linear_mps"],
                                     msg["angular_radps"])
    # hand-worked: mount velocity = (-r*y, r*x) = (0.26875, 0.6685)
    np.testing.assert_allclose(out["vx_mps"], 0.26875, atol=1e-9)
    np.testing.assert_allclose(out["vy_mps"], 0.6685, atol=1e-9)
    np.testing.assert_allclose(out["yaw_rate_radps"], 1.0, atol=1e-12)
    vx, vy = t265.robot_velocity_from_mount(out["vx_mps"], out["vy_mps"], out["yaw_rate_radps"], MOUNT)
    np.testing.assert_allclose(vx, 0.0, atol=1e-9)
    np.testing.assert_allclose(vy, 0.0, atol=1e-9)
    # robot centre does not move (eq. 5.8-5.9)
    track = t265.robot_position_from_pose(msg["position_m"], msg["orientation_xyzw"], MOUNT)
    np.testing.assert_allclose(track, 0.0, atol=1e-9)


def test_zeroing_puts_first_pose_at_origin():
    # camera powered on somewhere arbitrary: first message already has an offset pose
    q0 = np.array([0.0, np.sin(0.3), 0.0, np.cos(0.3)])  # 0.6 rad yaw
    pos = np.array([[2.0, 0.1, -3.0], [2.0, 0.1, -3.5]])
    out = t265.t265_odometry_to_body(pos, [q0, q0], np.zeros((2, 3)), np.zeros((2, 3)))
    assert out["yaw_raw_rad"][0] == pytest.approx(0.6)
    assert out["yaw_rad"][0] == pytest.approx(0.0)
    assert (out["x_m"][0], out["y_m"][0]) == pytest.approx((0.0, 0.0))
    track = t265.robot_position_from_pose(pos, [q0, q0], MOUNT)
    assert track[0] == pytest.approx((0.0, 0.0))
    # second sample moved 0.5 m along -z (camera forward at power-on) while yawed by 0.6:
    # in the zeroed world (x = start heading) that is 0.5 m forward rotated by -0.6
    assert out["x_m"][1] == pytest.approx(0.5 * np.cos(0.6))
    assert out["y_m"][1] == pytest.approx(-0.5 * np.sin(0.6))


def test_inverse_roundtrip_on_a_curve():
    rng = np.random.default_rng(0)
    n = 50
    yaw = np.cumsum(rng.normal(0, 0.2, n))
    x, y = rng.normal(0, 2, n), rng.normal(0, 2, n)
    vx, vy, r = rng.normal(1, 0.3, n), rng.normal(0, 0.3, n), rng.normal(0, 0.5, n)
    msg = t265.body_to_t265_odometry(x, y, yaw, vx, vy, r, MOUNT, start_pose=(x[0], y[0], yaw[0]))
    out = t265.t265_odometry_to_body(msg["position_m"], msg["orientation_xyzw"], msg["linear_mps"],
                                     msg["angular_radps"])
    bx, by = t265.robot_velocity_from_mount(out["vx_mps"], out["vy_mps"], out["yaw_rate_radps"], MOUNT)
    np.testing.assert_allclose(bx, vx, atol=1e-9)
    np.testing.assert_allclose(by, vy, atol=1e-9)
    np.testing.assert_allclose(out["yaw_rate_radps"], r, atol=1e-9)
    np.testing.assert_allclose(out["yaw_rad"], t265.wrap_angle(yaw - yaw[0]), atol=1e-9)


def test_t265_imu_axes():
    # IMU frame: x left, y up, z forward -> body x fwd, y left, z up
    np.testing.assert_allclose(t265.imu_to_body([[0, 0, 1.0]]), [[1, 0, 0]], atol=1e-12)
    np.testing.assert_allclose(t265.imu_to_body([[1.0, 0, 0]]), [[0, 1, 0]], atol=1e-12)
    np.testing.assert_allclose(t265.imu_to_body([[0, 9.81, 0]]), [[0, 0, 9.81]], atol=1e-12)


def test_reference_robot_mount_is_the_thesis_mount():
    cam = load_robot().camera
    assert (cam.x_m, cam.y_m) == pytest.approx(MOUNT[:2])
