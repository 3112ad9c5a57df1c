"""Figures like thesis Fig. 6.1-6.6 and 7.2-7.4 (matplotlib, Agg backend)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.figure import Figure  # no pyplot: no global figure state, no backend switch

from terrainml.estimation.consistency import nis_band
from terrainml.estimation.run import Diagnostics
from terrainml.robot import RobotSpec
from terrainml.schema import EST_VX, EST_VY, EST_YAW_RATE, wheel_col


def wheel_kinematics_twist(run: pd.DataFrame, robot: RobotSpec) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Body twist (vx, vy, r) from the wheels alone (forward kinematics, least squares per tick;
    the "AgriMaRo FB" curve of thesis Fig. 6.1)."""
    N = robot.n_wheels
    om = np.column_stack([run[wheel_col("omega", i)].to_numpy(float) for i in range(1, N + 1)])
    d = np.column_stack([run[wheel_col("steer", i)].to_numpy(float) if robot.wheels[i - 1].steerable
                         else np.zeros(len(run)) for i in range(1, N + 1)])
    x = np.array([w.x_m for w in robot.wheels])
    y = np.array([w.y_m for w in robot.wheels])
    c, s = np.cos(d), np.sin(d)
    A = np.stack([c, s, -y * c + x * s], axis=-1)  # (n, N, 3): v_long = A @ [vx, vy, r]
    b = om * robot.wheel_radius_m
    out = np.full((len(run), 3), np.nan)
    ok = np.isfinite(b).all(axis=1) & np.isfinite(A).all(axis=(1, 2))
    if ok.any():
        pinv = np.linalg.pinv(A[ok])
        out[ok] = np.einsum("nij,nj->ni", pinv, b[ok])
    return out[:, 0], out[:, 1], out[:, 2]


def save_plots(run: pd.DataFrame, est: pd.DataFrame, diag: Diagnostics, robot: RobotSpec,
               out_dir: str | Path) -> list[Path]:
    """Write the estimation figures into ``out_dir``; returns the file paths."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    t = est["t_s"].to_numpy()
    files = _twist_figures(run, est, robot, t, out_dir)
    files += _innovation_figures(diag, t, out_dir)
    files.append(_slip_figure(est, robot, t, out_dir))
    files.append(_nis_figure(est, t, out_dir))
    return files


def _save(f: Figure, path: Path) -> Path:
    f.tight_layout()
    f.savefig(path, dpi=110)
    return path


def _twist_figures(run: pd.DataFrame, est: pd.DataFrame, robot: RobotSpec, t, out_dir: Path) -> list[Path]:
    """vx, vy, yaw rate (Fig. 6.1, 6.3, 6.5): wheel kinematics, camera, IMU, truth and the EKF."""
    files: list[Path] = []
    fk_vx, fk_vy, fk_r = wheel_kinematics_twist(run, robot)
    has_cam = "cam_vx_mps" in run.columns
    has_gt = "gt_vx_mps" in run.columns
    series = [("vx", EST_VX, "cam_vx_mps", fk_vx, "gt_vx_mps", "longitudinal velocity [m/s]", "6_1"),
              ("vy", EST_VY, "cam_vy_mps", fk_vy, "gt_vy_mps", "lateral velocity [m/s]", "6_3"),
              ("yaw_rate", EST_YAW_RATE, "cam_yaw_rate_radps", fk_r, "gt_yaw_rate_radps",
               "yaw rate [rad/s]", "6_5")]
    for name, ekf_col, cam_col, fk, gt_col, label, fig in series:
        f = Figure(figsize=(10, 4))
        ax = f.subplots()
        ax.plot(t, fk, lw=0.6, alpha=0.7, label="wheel kinematics")
        if has_cam:
            ax.plot(t, run[cam_col].to_numpy(), lw=0.6, alpha=0.7, label="camera (at mount)")
        if name == "yaw_rate":
            ax.plot(t, run["imu_yaw_rate_radps"].to_numpy(), lw=0.5, alpha=0.5, label="IMU")
        if has_gt:
            ax.plot(t, run[gt_col].to_numpy(), "k--", lw=0.8, label="truth")
        ax.plot(t, est[ekf_col].to_numpy(), lw=1.2, label="EKF")
        ax.set_xlabel("t [s]")
        ax.set_ylabel(label)
        ax.legend(loc="best", fontsize=8)
        ax.grid(alpha=0.3)
        files.append(_save(f, out_dir / f"fig{fig}_{name}.png"))
    return files


def _innovation_figures(diag: Diagnostics, t, out_dir: Path) -> list[Path]:
    """Camera-row innovations (Fig. 6.2, 6.4, 6.6), their variance in the title."""
    files: list[Path] = []
    for row, fig in (("cam_vx", "6_2"), ("cam_vy", "6_4"), ("cam_yaw_rate", "6_6")):
        if row not in diag.rows:
            continue
        y = diag.innovation[:, diag.rows.index(row)]
        f = Figure(figsize=(10, 3))
        ax = f.subplots()
        ax.plot(t, y, lw=0.6)
        m = np.isfinite(y)
        ax.set_title(f"innovation {row}: var {np.var(y[m]) if m.any() else float('nan'):.2e}")
        ax.set_xlabel("t [s]")
        ax.grid(alpha=0.3)
        files.append(_save(f, out_dir / f"fig{fig}_innovation_{row}.png"))
    return files


def _slip_figure(est: pd.DataFrame, robot: RobotSpec, t, out_dir: Path) -> Path:
    """Slip per wheel (Fig. 7.2-7.4), truth dashed where the run has it."""
    N = robot.n_wheels
    f = Figure(figsize=(10, 2.2 * N))
    axes = f.subplots(N, 1, sharex=True, squeeze=False)
    for i in range(N):
        ax = axes[i, 0]
        ax.plot(t, est[f"slip{i + 1}"].to_numpy(), lw=0.7, label=f"slip{i + 1} (EKF)")
        if f"gt_slip{i + 1}" in est.columns:
            ax.plot(t, est[f"gt_slip{i + 1}"].to_numpy(), "k--", lw=0.8, label="truth")
        ax.set_ylim(-1.05, 1.05)
        ax.legend(loc="upper right", fontsize=8)
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("t [s]")
    return _save(f, out_dir / "fig7_slip_per_wheel.png")


def _nis_figure(est: pd.DataFrame, t, out_dir: Path) -> Path:
    """NIS with the 95 % chi-square band."""
    nis = est["nis"].to_numpy(float)
    dof = est["nis_dof"].to_numpy(float)
    lo, hi = nis_band(dof)
    f = Figure(figsize=(10, 3))
    ax = f.subplots()
    ax.semilogy(t, np.where(dof > 0, nis, np.nan), lw=0.5, label="NIS")
    ax.semilogy(t, hi, "r--", lw=0.8, label="95% band")
    ax.semilogy(t, np.maximum(lo, 1e-6), "r--", lw=0.8)
    ax.set_xlabel("t [s]")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    return _save(f, out_dir / "nis.png")
