"""Synthetic EST tables (contract 2) whose windows' truth is known by construction."""

from __future__ import annotations

import numpy as np
import pandas as pd


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


# a sensor-level run table (canonical, design §5) for the estimator -> windows chain
from synthetic_runs import CLASS_CURRENT_A, CLASS_SLIP, make_run_table  # noqa: E402,F401
