"""Low-level control of the simulated robot: inverse kinematics (thesis eq. 2.2, 2.5).

The per-wheel velocity PI with current limit runs inside the physics kernel
(:func:`terrainml.sim.physics.run_substeps`, like the ODrive's loop); this module turns a body twist
into wheel speed and steering set-points.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from terrainml.sim.physics import njit


@dataclass(frozen=True)
class DriveGains:
    """Velocity PI per wheel (torque = Kp e + Ki int e, clipped to the robot's max torque)."""

    kp_nms_per_rad: float = 6.0
    ki_nm_per_rad: float = 30.0
    steer_tau_s: float = 0.05
    omega_lag_tau_s: float = 0.040     # drive's speed estimate filter (thesis §7.2.2)



@njit(cache=True)
def _ik_kernel(vx, vy, r, wx, wy, radius, steer_now, steerable, min_speed, omega, delta):
    """Swerve inverse kinematics of every wheel, in place on ``omega`` (rad/s) and ``delta`` (rad).

    Numba kernel: takes flat arrays and scalars, because numba compiles a call with plain arrays
    and numbers without boxing a record, and the simulator calls it every control tick. Body
    twist ``vx, vy`` (m/s), ``r`` (rad/s); wheel positions ``wx, wy`` (N,) (m); ``radius`` (m);
    below ``min_speed`` (m/s) at the wheel a steerable wheel keeps ``steer_now``.
    """
    for i in range(wx.shape[0]):
        px = vx - r * wy[i]
        py = vy + r * wx[i]
        speed = math.sqrt(px * px + py * py)
        if steerable[i] == 0:
            delta[i] = 0.0
            omega[i] = px / radius
            continue
        if speed <= min_speed:
            delta[i] = steer_now[i]
            omega[i] = 0.0
            continue
        base = math.atan2(py, px)
        k = np.round((steer_now[i] - base) / math.pi)
        delta[i] = base + k * math.pi
        omega[i] = (speed if (int(k) % 2) == 0 else -speed) / radius


def inverse_kinematics(vx_mps: float, vy_mps: float, yaw_rate_radps: float, wheel_x_m: np.ndarray,
                       wheel_y_m: np.ndarray, radius_m: float, steer_now_rad: np.ndarray,
                       steerable: np.ndarray, min_speed_mps: float = 1e-3) -> tuple[np.ndarray, np.ndarray]:
    """Wheel speed (rad/s) and steering (rad) set-points for a body twist (thesis eq. 2.2, 2.5).

    Contact-point velocity ``p_i = (vx - r y_i, vy + r x_i)`` (eq. 2.2); for each steerable module
    both solutions ``delta = atan2(p_y, p_x) + k pi`` with ``omega = (-1)^k |p| / R`` (eq. 2.5) are
    considered and the one closest to the current steering angle is taken (minimal steering motion).
    Below ``min_speed_mps`` the module keeps its angle. Fixed wheels (skid steer) get the projection
    of the contact velocity on their heading (steering 0).

    Returns
    -------
    omega_radps : (N,), delta_rad : (N,) (continuous, not wrapped, so the actuator never spins round).
    """
    n = len(wheel_x_m)
    omega = np.empty(n)
    delta = np.empty(n)
    _ik_kernel(float(vx_mps), float(vy_mps), float(yaw_rate_radps), np.asarray(wheel_x_m, float),
               np.asarray(wheel_y_m, float), float(radius_m), np.asarray(steer_now_rad, float),
               np.asarray(steerable, np.int64), float(min_speed_mps), omega, delta)
    return omega, delta
