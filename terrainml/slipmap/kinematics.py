"""Skid-steer slippage quantities (IRLS paper eq. 5-8).

Frames: ``body`` (x forward, y left, z up). Left/right refer to the robot's own sides (the side
with y > 0 is left). All speeds in m/s, wheel speeds in rad/s, angles in rad.
"""

from __future__ import annotations

import numpy as np


def longitudinal_slippage_mps(omega_left_radps, omega_right_radps, vx_mps, yaw_rate_radps,
                              wheel_radius_m: float, track_width_m: float):
    """Longitudinal slippage of the left and right track (paper eq. 5-6).

    ``beta_i = v_enc_i - v_track_i`` with ``v_enc_i = R omega_i`` and the expected track speed from the
    body motion, ``v_track_L = v_x - omega B / 2``, ``v_track_R = v_x + omega B / 2``.
    Positive in traction (the track turns faster than the ground passes under it).

    Parameters
    ----------
    omega_left_radps, omega_right_radps : array, shape (n,)  encoder speeds (rad/s)
    vx_mps : array, shape (n,)  body-frame forward velocity (m/s)
    yaw_rate_radps : array, shape (n,)  body yaw rate (rad/s)
    wheel_radius_m : sprocket/wheel radius R (m)
    track_width_m : distance B between the left and right track centre lines (m)

    Returns
    -------
    (beta_left_mps, beta_right_mps) : arrays, shape (n,)
    """
    vx = np.asarray(vx_mps, dtype=float)
    r = np.asarray(yaw_rate_radps, dtype=float)
    v_track_l = vx - r * track_width_m / 2.0
    v_track_r = vx + r * track_width_m / 2.0
    beta_l = wheel_radius_m * np.asarray(omega_left_radps, dtype=float) - v_track_l
    beta_r = wheel_radius_m * np.asarray(omega_right_radps, dtype=float) - v_track_r
    return beta_l, beta_r


def lateral_slip_angle_rad(vx_mps, vy_mps):
    """Lateral (side) slip angle ``alpha = atan2(v_y, v_x)`` (paper eq. 7)."""
    return np.arctan2(np.asarray(vy_mps, dtype=float), np.asarray(vx_mps, dtype=float))


def compensate_wheel_speed_radps(omega_radps, beta_mps, wheel_radius_m: float):
    """Slip-compensated wheel speed set-point ``omega_des = omega + beta / R`` (paper eq. 8)."""
    return np.asarray(omega_radps, dtype=float) + np.asarray(beta_mps, dtype=float) / wheel_radius_m


def wheel_speeds_from_twist_radps(v_mps, yaw_rate_radps, wheel_radius_m: float, track_width_m: float):
    """Unicycle inverse kinematics of a skid-steer robot: (omega_left, omega_right) in rad/s."""
    v = np.asarray(v_mps, dtype=float)
    r = np.asarray(yaw_rate_radps, dtype=float)
    return ((v - r * track_width_m / 2.0) / wheel_radius_m,
            (v + r * track_width_m / 2.0) / wheel_radius_m)


def side_geometry(robot) -> tuple[list[int], list[int], float]:
    """Left and right wheel indices (1-based) and the track width of a skid-steer ``RobotSpec``.

    Wheels with ``y_m > 0`` are left, ``y_m < 0`` right. The track width is the distance between the
    mean lateral positions of the two sides.

    Raises
    ------
    ValueError if the robot is not a skid/differential drive with wheels on both sides.
    """
    if robot.drive not in ("skid", "differential"):
        raise ValueError(f"robot '{robot.name}' has drive '{robot.drive}': slip maps need a skid-steer "
                         "(skid or differential) robot with left and right wheels")
    left = [i + 1 for i, w in enumerate(robot.wheels) if w.y_m > 0]
    right = [i + 1 for i, w in enumerate(robot.wheels) if w.y_m < 0]
    if not left or not right:
        raise ValueError(f"robot '{robot.name}' needs wheels on both sides (y_m > 0 and y_m < 0)")
    y_l = np.mean([robot.wheels[i - 1].y_m for i in left])
    y_r = np.mean([robot.wheels[i - 1].y_m for i in right])
    return left, right, float(y_l - y_r)
