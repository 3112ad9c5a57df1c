"""Slip plots of a simulated run, like thesis Fig. 7.2-7.4: true vs measured slip per wheel.

"Measured" slip here is a simple kinematic estimate without the EKF: design §7.1 slip from the raw
encoder speed (with the drive's 40 ms lag) and the wheel-centre longitudinal velocity computed from
the camera (mount velocity minus the omega x r lever arm, camera yaw rate, EMA alpha = 0.2 as
thesis §7.2.2) and the measured steering angles. It shows the transient artefacts the thesis
describes (sensor lag); the EKF's slip is plotted by ``terrainml estimate``.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only, no display
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from scipy.signal import lfilter  # noqa: E402

from terrainml.io.ingest import load_run  # noqa: E402
from terrainml.robot import RobotSpec, reference_robot  # noqa: E402
from terrainml.sim.truth import slip_sae  # noqa: E402
from terrainml.schema import wheel_col


def _ema(x: np.ndarray, alpha: float) -> np.ndarray:
    x = np.nan_to_num(np.asarray(x, float))
    zi = [alpha * x[0]] if len(x) else [0.0]
    return lfilter([1 - alpha], [1, -alpha], x, zi=zi)[0] if len(x) else x


def measured_slip(table: pd.DataFrame, robot) -> np.ndarray:
    """(n, N) kinematic slip estimate from encoders + camera (see module docstring)."""
    cam = robot.camera
    r = _ema(table["cam_yaw_rate_radps"].to_numpy(), 0.2)
    vmx = _ema(table["cam_vx_mps"].to_numpy(), 0.2)
    vmy = _ema(table["cam_vy_mps"].to_numpy(), 0.2)
    vx = vmx + r * cam.y_m
    vy = vmy - r * cam.x_m
    out = []
    for i, w in enumerate(robot.wheels, start=1):
        d = table[wheel_col("steer", i)].to_numpy()
        v_long = (vx - r * w.y_m) * np.cos(d) + (vy + r * w.x_m) * np.sin(d)
        v_ang = table[wheel_col("omega", i)].to_numpy() * robot.wheel_radius_m
        out.append(slip_sae(v_ang, v_long))
    return np.column_stack(out)


def plot_run(path: str | Path, out_dir: str | Path, robot: RobotSpec | None = None) -> list[Path]:
    """Write ``<stem>_slip.png`` (true and measured slip per wheel) and ``<stem>_speed.png``.

    ``robot``: the spec the run was simulated with (None: the reference robot).
    """
    robot = robot if robot is not None else reference_robot()
    res = load_run(path, robot=robot)
    if not res.report.usable:
        raise ValueError(f"{path}: no usable run table ({'; '.join(res.report.errors)})")
    t = res.table
    if "gt_slip1" not in t or robot.camera is None:
        raise ValueError(f"{path}: needs /sim/wheel_slip truth and a camera (simulated runs of a robot with a camera)")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    meas = measured_slip(t, robot)
    ts = t["t_s"].to_numpy()
    n = robot.n_wheels
    fig, axes = plt.subplots(n, 1, figsize=(10, 2.6 * n), sharex=True, squeeze=False)
    for i in range(n):
        ax = axes[i, 0]
        ax.plot(ts, meas[:, i], lw=0.7, color="tab:orange", label="measured (encoder + camera, no EKF)")
        ax.plot(ts, t[f"gt_slip{i + 1}"].to_numpy(), lw=1.2, color="tab:blue", label="true")
        ax.set_ylabel(f"slip wheel {i + 1}")
        ax.set_ylim(-1.05, 1.05)
        ax.grid(alpha=0.3)
    axes[0, 0].legend(loc="upper right", fontsize=8)
    axes[-1, 0].set_xlabel("t (s)")
    stem = Path(path).stem
    terrain = int(t["terrain"].iloc[0]) if "terrain" in t else -1
    fig.suptitle(f"{stem}: longitudinal slip (terrain id {terrain})")
    fig.tight_layout()
    p1 = out_dir / f"{stem}_slip.png"
    fig.savefig(p1, dpi=110)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(10, 3))
    ax.plot(ts, t["gt_vx_mps"], label="true vx")
    if "cmd_vx_mps" in t:
        ax.plot(ts, t["cmd_vx_mps"], "--", label="cmd vx")
    ax.plot(ts, t["wheel1_omega_radps"] * robot.wheel_radius_m, lw=0.7, label="wheel 1 omega R (encoder)")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("m/s")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    p2 = out_dir / f"{stem}_speed.png"
    fig.savefig(p2, dpi=110)
    plt.close(fig)
    return [p1, p2]
