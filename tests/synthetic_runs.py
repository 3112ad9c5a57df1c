"""Synthetic canonical run tables shared by the features and models tests.

A straight drive at a constant speed over one "terrain" whose slip and motor current grow with
the class id, so the true class of every window is known by construction (independent of the
simulator). The tables go through the real ingest and the real EKF in the tests that use them.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from terrainml.robot import load_robot

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
