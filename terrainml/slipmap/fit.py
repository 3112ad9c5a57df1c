"""Fit a slip map from canonical run tables (design §5) of a skid-steer robot.

Inputs per row: the left and right wheel speeds (mean of each side's ``wheel{i}_omega_radps``) and a
reference body velocity, from the first source that is present and finite:

1. simulator truth ``gt_vx_mps``, ``gt_vy_mps``, ``gt_yaw_rate_radps``;
2. camera ``cam_vx_mps``, ``cam_vy_mps`` (mount velocity in body axes, moved to the body origin with
   the robot spec's camera lever arm: ``v_body = v_cam - omega x r_cam``) and the yaw rate
   ``cam_yaw_rate_radps`` (else ``imu_yaw_rate_radps``).

Targets are paper eq. 5-7. Rows with ``|v_x| < min_speed_mps`` (slip angle undefined), invalid
wheel or camera samples, or non-finite values are dropped. Entries are terrain class names (column
``terrain``) or ``"all"``.
"""

from __future__ import annotations

from typing import Iterable

import numpy as np
import pandas as pd

from terrainml.classes import class_name
from terrainml.slipmap.kinematics import lateral_slip_angle_rad, longitudinal_slippage_mps, side_geometry
from terrainml.slipmap.slipmap import SlipMap, SlipMapConfig
from terrainml.schema import wheel_col


class SlipFitError(ValueError):
    """A run table cannot be used for a slip map (the message names the column)."""


def slip_samples(table: pd.DataFrame, robot, *, min_speed_mps: float = 0.05, source: str = "run table"):
    """Wheel speeds, targets and entry keys of one run table.

    Returns
    -------
    omega_lr : array, shape (n, 2) rad/s; targets : array, shape (n, 3); keys : array of str, shape (n,);
    velocity_source : "gt" or "cam"
    """
    left, right, track_m = side_geometry(robot)
    for i in left + right:
        if wheel_col("omega", i) not in table.columns:
            raise SlipFitError(f"{source}: missing column '{wheel_col('omega', i)}'")
    wl = table[[wheel_col("omega", i) for i in left]].to_numpy(float).mean(axis=1)
    wr = table[[wheel_col("omega", i) for i in right]].to_numpy(float).mean(axis=1)
    if all(c in table.columns for c in ("gt_vx_mps", "gt_vy_mps", "gt_yaw_rate_radps")) and \
            np.isfinite(table["gt_vx_mps"].to_numpy(float)).any():
        vx, vy, r = (table[c].to_numpy(float) for c in ("gt_vx_mps", "gt_vy_mps", "gt_yaw_rate_radps"))
        src = "gt"
        ok = np.ones(len(table), bool)
    elif "cam_vx_mps" in table.columns and "cam_vy_mps" in table.columns:
        r_col = "cam_yaw_rate_radps" if "cam_yaw_rate_radps" in table.columns else "imu_yaw_rate_radps"
        if r_col not in table.columns:
            raise SlipFitError(f"{source}: missing column 'cam_yaw_rate_radps' or 'imu_yaw_rate_radps'")
        r = table[r_col].to_numpy(float)
        cx, cy = (robot.camera.x_m, robot.camera.y_m) if robot.camera is not None else (0.0, 0.0)
        vx = table["cam_vx_mps"].to_numpy(float) + r * cy
        vy = table["cam_vy_mps"].to_numpy(float) - r * cx
        src = "cam"
        ok = table["cam_valid"].to_numpy(bool) if "cam_valid" in table.columns else np.ones(len(table), bool)
    else:
        raise SlipFitError(f"{source}: no reference body velocity: needs columns gt_vx_mps, gt_vy_mps, "
                           "gt_yaw_rate_radps (simulator) or cam_vx_mps, cam_vy_mps (camera)")
    if "wheels_valid" in table.columns:
        ok &= table["wheels_valid"].to_numpy(bool)
    bl, br = longitudinal_slippage_mps(wl, wr, vx, r, robot.wheel_radius_m, track_m)
    al = lateral_slip_angle_rad(vx, vy)
    y = np.c_[bl, br, al]
    x = np.c_[wl, wr]
    ok &= np.isfinite(x).all(axis=1) & np.isfinite(y).all(axis=1) & (np.abs(vx) >= min_speed_mps)
    if "terrain" in table.columns:
        ids = pd.to_numeric(table["terrain"], errors="coerce").fillna(-1).astype(int).to_numpy()
        keys = np.array([class_name(i) if i >= 0 else "unknown" for i in ids], dtype=object)
    else:
        keys = np.full(len(table), "all", dtype=object)
    return x[ok], y[ok], keys[ok], src


def fit_slip_map(tables: Iterable[tuple[str, pd.DataFrame]], robot, *, by: str = "terrain",
                 config: SlipMapConfig | None = None, min_samples: int = 30, robot_id: str = "robot"):
    """Fit one :class:`SlipMap` from several run tables.

    Parameters
    ----------
    tables : iterable of (source name, run table)
    robot : RobotSpec of a skid-steer robot
    by : "terrain" (one entry per class in column ``terrain``) or "all" (one entry)
    config : map settings; default: cubic, Huber, input scale = 1 m/s over the wheel radius
    min_samples : entries with fewer usable rows are skipped

    Returns
    -------
    (SlipMap, info dict with per-entry sample counts and the velocity source of each table)
    """
    if by not in ("terrain", "all"):
        raise ValueError(f"by must be 'terrain' or 'all', got {by!r}")
    _, _, track_m = side_geometry(robot)
    config = config or SlipMapConfig(input_scale_radps=1.0 / robot.wheel_radius_m,
                                     wheel_radius_m=robot.wheel_radius_m, track_width_m=track_m)
    xs, ys, ks, sources = [], [], [], {}
    for name, table in tables:
        x, y, k, src = slip_samples(table, robot, source=name)
        xs.append(x)
        ys.append(y)
        ks.append(k if by == "terrain" else np.full(len(k), "all", dtype=object))
        sources[name] = src
    if not xs:
        raise SlipFitError("no run tables given")
    x, y, k = np.vstack(xs), np.vstack(ys), np.concatenate(ks)
    smap = SlipMap(config, robot_id=robot_id)
    counts = {}
    for key in sorted(set(k.tolist())):
        sel = k == key
        counts[key] = int(sel.sum())
        if sel.sum() >= max(min_samples, 11):
            smap.fit_patch(key, x[sel], y[sel])
    return smap, {"samples_per_entry": counts, "velocity_source": sources,
                  "fitted_entries": sorted(smap.patches)}
