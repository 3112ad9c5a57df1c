"""Synthetic EST tables (contract 2) whose windows' truth is known by construction."""

from __future__ import annotations

import numpy as np
import pandas as pd

from terrainml.robot import load_robot


def make_est(n: int = 1000, n_wheels: int = 3, speed_mps: float = 1.0, slip: float = 0.1,
             current_a: float = 3.0, terrain: int = 2, run_id: str = "run_a", seed: int = 0,
             rate_hz: float = 100.0) -> pd.DataFrame:
    """A steady straight run: constant speed, every wheel steady, all sensors valid, plus noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / rate_hz
    d = {"t_s": t, "ekf_x_m": speed_mps * t, "ekf_y_m": np.zeros(n), "ekf_yaw_rad": np.zeros(n),
         "ekf_vx_mps": speed_mps + 0.01 * rng.standard_normal(n), "ekf_vy_mps": 0.01 * rng.standard_normal(n),
         "ekf_yaw_rate_radps": 0.005 * rng.standard_normal(n), "ekf_ax_mps2": 0.02 * rng.standard_normal(n),
         "ekf_ay_mps2": 0.02 * rng.standard_normal(n)}
    for i in range(1, n_wheels + 1):
        d[f"ekf_steer{i}_rad"] = np.zeros(n)
    d["ekf_gyro_bias_radps"] = np.zeros(n)
    for i in range(1, n_wheels + 1):
        d[f"slip{i}"] = slip + 0.01 * rng.standard_normal(n)
    for i in range(1, n_wheels + 1):
        d[f"state{i}"] = np.full(n, "steady", dtype=object)
    for i in range(1, n_wheels + 1):
        d[f"v_long{i}_mps"] = np.full(n, speed_mps)
    d.update({"nis": np.ones(n), "nis_dof": np.full(n, 14), "estimator_ok": np.ones(n, dtype=bool),
              "slip_available": np.ones(n, dtype=bool)})
    for i in range(1, n_wheels + 1):
        d[f"wheel{i}_omega_radps"] = np.full(n, speed_mps * (1 + slip) / 0.165)
        d[f"wheel{i}_current_a"] = current_a + 0.2 * rng.standard_normal(n)
        d[f"wheel{i}_steer_rad"] = np.zeros(n)
    d["imu_ax_mps2"] = 0.05 * rng.standard_normal(n)
    d["imu_ay_mps2"] = 0.05 * rng.standard_normal(n)
    d["imu_az_mps2"] = 9.81 + 0.3 * rng.standard_normal(n)
    d["imu_yaw_rate_radps"] = np.zeros(n)
    for g in ("wheels", "steer", "current", "imu", "cam", "cmd"):
        d[f"{g}_valid"] = np.ones(n, dtype=bool)
    d["terrain"] = np.full(n, terrain, dtype=np.int64)
    d["run_id"] = np.full(n, run_id, dtype=object)
    return pd.DataFrame(d)


# a sensor-level run table (canonical, SYSTEM §5) for the estimator -> windows chain
CLASS_SLIP = {0: 0.01, 2: 0.12, 6: 0.30}
CLASS_CURRENT_A = {0: 1.0, 2: 3.0, 6: 6.0}


def make_run_table(terrain: int, run_id: str, seed: int, duration_s: float = 14.0,
                   speed_mps: float = 0.8) -> pd.DataFrame:
    robot = load_robot("agrimaro")
    rng = np.random.default_rng(seed)
    n = int(duration_s * 100)
    t = np.arange(n) / 100.0
    slip = CLASS_SLIP[terrain] * (1 + 0.1 * rng.standard_normal())
    cur = CLASS_CURRENT_A[terrain] * (1 + 0.1 * rng.standard_normal())
    accel = 0.5  # m/s^2 from rest, then cruise (the EKF starts at rest)
    v = np.minimum(accel * t, speed_mps)
    a = np.where(accel * t < speed_mps, accel, 0.0)
    d = {"t_s": t}
    R = robot.wheel_radius_m
    for i in range(1, robot.n_wheels + 1):
        d[f"wheel{i}_omega_radps"] = v * (1 + slip) / R + 0.02 * rng.standard_normal(n)
        d[f"wheel{i}_steer_rad"] = np.zeros(n)
        d[f"wheel{i}_current_a"] = cur + 0.3 * rng.standard_normal(n) + 0.2 * terrain * np.sin(
            2 * np.pi * (5 + terrain) * t)
    d["imu_ax_mps2"] = a + 0.01 * rng.standard_normal(n)
    d["imu_ay_mps2"] = 0.01 * rng.standard_normal(n)
    d["imu_az_mps2"] = 9.81 + (0.1 + 0.1 * terrain) * rng.standard_normal(n)
    d["imu_yaw_rate_radps"] = 0.002 * rng.standard_normal(n)
    d["imu_yaw_rad"] = np.zeros(n)
    d["cam_vx_mps"] = v + 0.005 * rng.standard_normal(n)
    d["cam_vy_mps"] = 0.005 * rng.standard_normal(n)
    d["cam_yaw_rate_radps"] = 0.002 * rng.standard_normal(n)
    d["cam_yaw_rad"] = np.zeros(n)
    d["terrain"] = np.full(n, terrain, dtype=np.int64)
    d["run_id"] = np.full(n, run_id, dtype=object)
    return pd.DataFrame(d)
