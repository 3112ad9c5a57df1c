"""Small kinematic runs with exactly known truth (independent of the simulator): public, for tests and benchmarks.

:func:`kinematic_run` turns a body-twist profile and a prescribed slip per wheel into a canonical
run table: wheel speeds from the inverse of the SAE slip definition (through a first-order
encoder lag), steering angles from swerve inverse kinematics, IMU specific force
``a = dv/dt + omega x v``, gyro with bias, camera-mount velocity in body axes (lever arm
``v + omega x r_cam``), all with white noise. Truth columns ``gt_*`` hold the exact values.

This module is part of the public API so that a user's own tests, and the project's tests and
benchmarks (``benchmarks/bench_estimation.py``, ``benchmarks/bench_stream.py``), can build such
runs; nothing in the io -> ... -> control chain imports it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import Any, Callable

import numpy as np
import pandas as pd

from terrainml.angles import wrap_angle
from terrainml.robot import RobotSpec, reference_robot
from terrainml.schema import valid_column, wheel_col


def wheel_speed_for_slip(v_long_mps, slip):
    """Peripheral speed omega R giving SAE slip ``slip`` at wheel-centre speed ``v_long`` (m/s).

    Traction (s >= 0, same sign): v_ang = v_long / (1 - s); braking (s < 0): v_ang = v_long (1 + s).
    """
    v = np.asarray(v_long_mps, dtype=float)
    s = np.asarray(slip, dtype=float)
    return np.where(s >= 0, v / np.maximum(1.0 - s, 1e-6), v * (1.0 + s))


def trapezoid_speed(t_s, cruise_mps=1.0, accel_mps2=1.0, t_start_s=1.0, t_brake_s=None,
                    decel_mps2=1.0):
    """Speed profile: rest, ramp at ``accel`` to ``cruise``, hold, optional ramp down (m/s)."""
    t = np.asarray(t_s, dtype=float)
    v = np.clip((t - t_start_s) * accel_mps2, 0.0, cruise_mps)
    if t_brake_s is not None:
        v = np.minimum(v, np.clip(cruise_mps - (t - t_brake_s) * decel_mps2, 0.0, cruise_mps))
    return v


__all__ = ["BodyMotion", "SensorNoise", "kinematic_run", "trapezoid_speed", "wheel_speed_for_slip"]


@dataclass(frozen=True)
class SensorNoise:
    """Sensor imperfections of a kinematic run.

    Attributes
    ----------
    encoder_tau_s : time constant of the encoders' first-order lag, s.
    omega_noise_radps : white noise of the wheel speeds, rad/s.
    cam_noise_mps : white noise of the camera-mount velocity, m/s.
    imu_acc_noise : white noise of the IMU specific force, m/s^2.
    gyro_noise : white noise of the gyro yaw rate, rad/s.
    gyro_bias : constant gyro yaw-rate bias, rad/s.
    imu_acc_bias : constant bias of the IMU's x specific force, m/s^2.
    """

    encoder_tau_s: float = 0.04
    omega_noise_radps: float = 0.01
    cam_noise_mps: float = 0.003
    imu_acc_noise: float = 0.02
    gyro_noise: float = 0.002
    gyro_bias: float = 0.003
    imu_acc_bias: float = 0.0


@dataclass(frozen=True)
class BodyMotion:
    """The prescribed motion of a kinematic run.

    Attributes
    ----------
    vx, vy, yaw_rate : callables t (s, array) -> value (m/s, m/s, rad/s), or None (a trapezoid to
        1 m/s, 0, 0).
    slip : callable t -> array (N,) of true slip per wheel, a float, or None (0).
    """

    vx: Callable | None = None
    vy: Callable | None = None
    yaw_rate: Callable | None = None
    slip: Callable | float | None = None


_MOTION_FIELDS = frozenset(f.name for f in fields(BodyMotion))
_NOISE_FIELDS = frozenset(f.name for f in fields(SensorNoise))


def _motion_and_noise(noise: SensorNoise | None, options: dict[str, Any]) -> tuple[BodyMotion, SensorNoise]:
    """The keyword options of :func:`kinematic_run` as its typed records (TypeError names an unknown one)."""
    unknown = set(options) - _MOTION_FIELDS - _NOISE_FIELDS
    if unknown:
        raise TypeError(f"kinematic_run: unknown option(s) {sorted(unknown)}; known: "
                        f"{sorted(_MOTION_FIELDS | _NOISE_FIELDS)}")
    motion = BodyMotion(**{k: v for k, v in options.items() if k in _MOTION_FIELDS})
    noise = replace(noise or SensorNoise(), **{k: v for k, v in options.items() if k in _NOISE_FIELDS})
    return motion, noise


def kinematic_run(robot: RobotSpec | None = None, *, duration_s: float = 20.0, rate_hz: float = 100.0,
                  seed: int = 0, cam_dropouts: tuple[tuple[float, float], ...] = (), terrain: int = 0,
                  run_id: str = "synthetic", noise: SensorNoise | None = None, **options: Any) -> pd.DataFrame:
    """A canonical run table with exact truth.

    Parameters
    ----------
    robot : RobotSpec (None: the reference robot).
    duration_s : length of the run, s; rate_hz : its tick rate, Hz.
    seed : seed of the noise generator.
    cam_dropouts : (t0, t1) intervals without camera samples, s.
    terrain : terrain class id of every tick; run_id : the run's id.
    noise : SensorNoise (None: its defaults).
    **options : fields of :class:`BodyMotion` (``vx``, ``vy``, ``yaw_rate``, ``slip``) and single
        fields of :class:`SensorNoise` overriding ``noise`` (e.g. ``imu_acc_noise=0.005``).

    Returns
    -------
    DataFrame (n_ticks, ...) canonical run table with ``gt_*`` columns.
    """
    motion, noise = _motion_and_noise(noise, options)
    robot = robot if robot is not None else reference_robot()
    rng = np.random.default_rng(seed)
    n = int(round(duration_s * rate_hz))
    dt = 1.0 / rate_hz
    t = np.arange(n) * dt
    vx_f = motion.vx or (lambda tt: trapezoid_speed(tt))
    vy_f = motion.vy or (lambda tt: np.zeros_like(tt))
    r_f = motion.yaw_rate or (lambda tt: np.zeros_like(tt))
    bvx, bvy, br = (np.asarray(f(t), dtype=float) * np.ones(n) for f in (vx_f, vy_f, r_f))
    S = _slip_matrix(motion.slip, t, robot.n_wheels)
    steer, v_long = _wheel_kinematics(robot, bvx, bvy, br)
    v_ang = wheel_speed_for_slip(v_long, S)
    omega_meas = _encoder(v_ang / robot.wheel_radius_m, dt, noise.encoder_tau_s)
    omega_meas += rng.normal(0, noise.omega_noise_radps, omega_meas.shape)
    yaw = np.cumsum(br) * dt
    yaw = yaw - yaw[0]
    df = pd.DataFrame({"t_s": t})
    for i in range(robot.n_wheels):
        df[wheel_col("omega", i + 1)] = omega_meas[:, i]
        df[wheel_col("steer", i + 1)] = steer[:, i] + (rng.normal(0, 0.002, n) if robot.wheels[i].steerable else 0)
        df[wheel_col("current", i + 1)] = 5.0 * S[:, i] + rng.normal(0, 0.1, n)
    _imu_columns(df, rng, bvx, bvy, br, yaw, dt, noise)
    if robot.camera is not None:
        _camera_columns(df, rng, robot, bvx, bvy, br, yaw, noise.cam_noise_mps, cam_dropouts)
    for g in ("wheels", "steer", "current", "imu"):
        df[valid_column(g).name] = True
    df["terrain"] = terrain
    df["run_id"] = run_id
    _truth_columns(df, bvx, bvy, br, yaw, dt, S, v_long, v_ang)
    df.attrs["terrainml"] = {"robot_spec": robot.to_json(), "rate_hz": rate_hz, "source_file": "synthetic"}
    return df


def _slip_matrix(slip, t: np.ndarray, n_wheels: int) -> np.ndarray:
    """True slip per tick and wheel (n, N) from a callable, a float or None (0)."""
    n = len(t)
    if slip is None:
        return np.zeros((n, n_wheels))
    if callable(slip):
        return np.array([np.broadcast_to(slip(tt), (n_wheels,)) for tt in t], dtype=float)
    return np.full((n, n_wheels), float(slip))


def _wheel_kinematics(robot: RobotSpec, bvx, bvy, br) -> tuple[np.ndarray, np.ndarray]:
    """Steering angles (n, N) from swerve inverse kinematics and wheel-centre v_long (n, N)."""
    n, N = len(bvx), robot.n_wheels
    wx = np.array([w.x_m for w in robot.wheels])
    wy = np.array([w.y_m for w in robot.wheels])
    u = bvx[:, None] - br[:, None] * wy
    w = bvy[:, None] + br[:, None] * wx
    steer = np.zeros((n, N))
    for i, wh in enumerate(robot.wheels):
        if wh.steerable:
            ang = np.arctan2(w[:, i], u[:, i])
            # keep |delta| <= pi/2 by driving the wheel backwards (module flip)
            ang = np.where(ang > math.pi / 2, ang - math.pi, ang)
            ang = np.where(ang < -math.pi / 2, ang + math.pi, ang)
            # hold the last angle when the wheel is (nearly) stopped
            moving = np.hypot(u[:, i], w[:, i]) > 1e-3
            idx = np.where(moving, np.arange(n), 0)
            np.maximum.accumulate(idx, out=idx)
            steer[:, i] = np.where(moving.any(), ang[idx], 0.0)
    return steer, u * np.cos(steer) + w * np.sin(steer)


def _encoder(omega_true: np.ndarray, dt: float, tau_s: float) -> np.ndarray:
    """Encoder reading: first-order lag (ODrive filtering) of the true wheel speed (n, N), rad/s."""
    a = 1.0 - math.exp(-dt / tau_s) if tau_s > 0 else 1.0
    out = np.empty_like(omega_true)
    y = omega_true[0].copy()
    for k in range(len(omega_true)):
        y = y + a * (omega_true[k] - y)
        out[k] = y
    return out


def _imu_columns(df, rng, bvx, bvy, br, yaw, dt, noise: SensorNoise) -> None:
    """IMU specific force a = dv/dt + omega x v (body axes), gyro rate and yaw with bias and noise."""
    n = len(bvx)
    imu_acc_noise, imu_acc_bias = noise.imu_acc_noise, noise.imu_acc_bias
    gyro_noise, gyro_bias = noise.gyro_noise, noise.gyro_bias
    t = df["t_s"].to_numpy()
    ax = np.gradient(bvx, dt) - br * bvy
    ay = np.gradient(bvy, dt) + br * bvx
    df["imu_ax_mps2"] = ax + imu_acc_bias + rng.normal(0, imu_acc_noise, n)
    df["imu_ay_mps2"] = ay + rng.normal(0, imu_acc_noise, n)
    df["imu_az_mps2"] = 9.81 + rng.normal(0, imu_acc_noise, n)
    df["imu_yaw_rate_radps"] = br + gyro_bias + rng.normal(0, gyro_noise, n)
    df["imu_yaw_rad"] = yaw + gyro_bias * t + rng.normal(0, 1e-3, n)


def _camera_columns(df, rng, robot: RobotSpec, bvx, bvy, br, yaw, cam_noise_mps, cam_dropouts):
    """Camera-mount velocity in body axes (lever arm v + omega x r_cam), rate and yaw; gaps as NaN."""
    n, cam = len(bvx), robot.camera
    t = df["t_s"].to_numpy()
    cam_ok = np.ones(n, dtype=bool)
    for t0, t1 in cam_dropouts:
        cam_ok &= ~((t >= t0) & (t < t1))
    df["cam_vx_mps"] = np.where(cam_ok, bvx - br * cam.y_m + rng.normal(0, cam_noise_mps, n), np.nan)
    df["cam_vy_mps"] = np.where(cam_ok, bvy + br * cam.x_m + rng.normal(0, cam_noise_mps, n), np.nan)
    df["cam_yaw_rate_radps"] = np.where(cam_ok, br + rng.normal(0, 0.01, n), np.nan)
    df["cam_yaw_rad"] = np.where(cam_ok, yaw + rng.normal(0, 1e-3, n), np.nan)
    df["cam_valid"] = cam_ok


def _truth_columns(df, bvx, bvy, br, yaw, dt, S, v_long, v_ang) -> None:
    """``gt_*`` columns: body twist, world pose, slip per wheel (0 where the wheel stands)."""
    df["gt_vx_mps"] = bvx
    df["gt_vy_mps"] = bvy
    df["gt_yaw_rate_radps"] = br
    df["gt_x_m"] = np.cumsum(bvx * np.cos(yaw) - bvy * np.sin(yaw)) * dt
    df["gt_y_m"] = np.cumsum(bvx * np.sin(yaw) + bvy * np.cos(yaw)) * dt
    df["gt_yaw_rad"] = wrap_angle(yaw)
    moving = np.abs(v_long) >= 0.05
    for i in range(S.shape[1]):
        df[f"gt_slip{i + 1}"] = np.where(moving[:, i] | (np.abs(v_ang[:, i]) >= 0.05), S[:, i], 0.0)
