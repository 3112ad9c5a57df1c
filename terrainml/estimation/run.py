"""Offline estimation of a whole run table: the EST table of contract 2.

:func:`estimate_run` converts the run table to numpy once and loops over
:meth:`OnlineEstimator.core` (the code the online path runs), so ``estimate_run(table)`` equals
feeding the rows one by one to :meth:`OnlineEstimator.step`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import pandas as pd

from terrainml.estimation.ekf import EkfPreset
from terrainml.estimation.online import OnlineEstimator, est_state_columns, passthrough_columns
from terrainml.robot import RobotSpec, reference_robot
from terrainml.schema import (EST_BODY_COLUMNS, EST_GYRO_BIAS, EST_HEALTH_COLUMNS, WHEEL_STATES, est_wheel_col,
                              infer_n_wheels, table_metadata, valid_column, wheel_col)


@dataclass
class Diagnostics:
    """Per-tick filter diagnostics of an offline run.

    Attributes
    ----------
    rows : list of str, measurement row names (e.g. ``cam_vx``), order of the arrays' columns.
    innovation : ndarray (n_ticks, m), y = z - h(x) (NaN where the row was not used).
    innovation_var : ndarray (n_ticks, m), S_ii (NaN where not used).
    n_gated : int, camera rows rejected by the robust preset's gate.
    preset : str
    """

    rows: list[str]
    innovation: np.ndarray
    innovation_var: np.ndarray
    n_gated: int = 0
    preset: str = ""
    extra: dict = field(default_factory=dict)


def run_robot(table: pd.DataFrame, robot: RobotSpec | None = None) -> RobotSpec:
    """``robot``; None: the spec the table's metadata carries, else the reference robot."""
    if robot is not None:
        return robot
    spec = table_metadata(table).get("robot_spec")
    if spec:
        return RobotSpec.from_json(spec if isinstance(spec, str) else json.dumps(spec))
    return reference_robot()


def estimate_run_detailed(table: pd.DataFrame, robot: RobotSpec | None = None,
                          preset: str | EkfPreset = "robust",
                          progress: Callable[[int, int], None] | None = None,
                          on_tick: Callable[[int, OnlineEstimator], None] | None = None,
                          reference: bool = False) -> tuple[pd.DataFrame, Diagnostics]:
    """Like :func:`estimate_run`, also returning :class:`Diagnostics` (innovations, S).

    ``progress(k, n)`` is called about 100 times; ``on_tick(k, estimator)`` after every tick
    (tests use it to inspect ``estimator.ekf.P``). ``reference``: run the numpy reference filter
    (:mod:`terrainml.estimation.reference`) instead of the compiled one (same numbers, slower).
    """
    robot = run_robot(table, robot)
    n_wh = infer_n_wheels(table)
    if n_wh != robot.n_wheels:
        raise ValueError(f"run table has {n_wh} wheel(s) (wheel{{i}}_omega_radps columns) but robot "
                         f"spec '{robot.name}' has {robot.n_wheels}")
    cols = set(table.columns)
    est = OnlineEstimator(robot, preset, has_imu_yaw="imu_yaw_rad" in cols,
                          has_cam_yaw="cam_yaw_rad" in cols, reference=reference)
    n = len(table)
    m = len(est.row_columns)
    N = robot.n_wheels
    t, Z, V, omega = _measurements(table, est, N)

    out_x = np.empty((n, est.model.n))
    out_steer = np.empty((n, N))
    out_slip = np.empty((n, N))
    out_state = np.empty((n, N), dtype=np.int8)
    out_vlong = np.empty((n, N))
    out_nis = np.empty(n)
    out_dof = np.empty(n, dtype=np.int64)
    out_ok = np.empty(n, dtype=bool)
    out_sa = np.empty(n, dtype=bool)
    innov = np.empty((n, m))
    innov_var = np.empty((n, m))
    ekf = est.ekf
    step_every = max(1, n // 100)
    for k in range(n):
        est.core(t[k], Z[k], V[k], omega[k])
        out_x[k] = ekf.x
        out_steer[k] = est.steer
        out_slip[k] = est.slip
        out_state[k] = est.state
        out_vlong[k] = est.v_long
        out_nis[k] = ekf.nis
        out_dof[k] = ekf.nis_dof
        out_ok[k] = est.estimator_ok
        out_sa[k] = est.slip_available
        innov[k] = ekf.y
        innov_var[k] = ekf.S_diag
        if on_tick is not None:
            on_tick(k, est)
        if progress is not None and k % step_every == 0:
            progress(k, n)
    if progress is not None:
        progress(n, n)

    df = _est_table(table, robot, est, t, out_x, out_steer, out_slip, out_state, out_vlong,
                    dict(zip(EST_HEALTH_COLUMNS, (out_nis, out_dof, out_ok, out_sa))))
    diag = Diagnostics(rows=[r.name for r in est.model.rows], innovation=innov,
                       innovation_var=innov_var, n_gated=ekf.n_gated, preset=est.preset.name)
    return df, diag


def _measurements(table: pd.DataFrame, est: OnlineEstimator, N: int):
    """The run table as the estimator's arrays: t (n,), rows Z (n, m), usable V (n, m), omega (n, N).

    A row is usable where its value is finite and its sensor group valid; omega is NaN where the
    wheels are invalid.
    """
    cols = set(table.columns)
    n, m = len(table), len(est.row_columns)
    t = table["t_s"].to_numpy(dtype=float)
    Z = np.full((n, m), np.nan)
    for k, c in enumerate(est.row_columns):
        if c in cols:
            Z[:, k] = table[c].to_numpy(dtype=float)
    gv = {}
    for g in ("wheels", "imu", "cam", "steer"):
        name = valid_column(g).name
        gv[g] = table[name].to_numpy(dtype=bool) if name in cols else np.ones(n, dtype=bool)
    V = np.isfinite(Z)
    for k, g in enumerate(est.row_groups):
        V[:, k] &= gv[g]
    omega = np.column_stack([table[wheel_col("omega", i)].to_numpy(dtype=float) for i in range(1, N + 1)])
    omega = np.where(gv["wheels"][:, None], omega, np.nan)
    return t, Z, V, omega


def _est_table(table: pd.DataFrame, robot: RobotSpec, est: OnlineEstimator, t, out_x, out_steer, out_slip,
               out_state, out_vlong, health: dict) -> pd.DataFrame:
    """The EST table (contract 2) of the per-tick outputs, pass-through columns copied from ``table``."""
    N = robot.n_wheels
    data: dict[str, object] = {"t_s": t}
    for j, name in enumerate(EST_BODY_COLUMNS):   # the first eight EKF states, in order
        data[name] = out_x[:, j]
    for i in range(N):
        data[est_wheel_col("steer", i + 1)] = out_steer[:, i]
    data[EST_GYRO_BIAS] = out_x[:, est.model.i_bias]
    names = np.asarray(WHEEL_STATES, dtype=object)
    for i in range(N):
        data[est_wheel_col("slip", i + 1)] = out_slip[:, i]
    for i in range(N):
        data[est_wheel_col("state", i + 1)] = names[out_state[:, i]]
    for i in range(N):
        data[est_wheel_col("v_long", i + 1)] = out_vlong[:, i]
    data.update(health)
    df = pd.DataFrame(data, columns=est_state_columns(N))
    for i in range(N):
        df[est_wheel_col("state", i + 1)] = df[est_wheel_col("state", i + 1)].astype(str)
    for c in passthrough_columns(N, list(table.columns)):
        df[c] = table[c].to_numpy()
    df.attrs["terrainml"] = dict(table_metadata(table), estimation_preset=est.preset.name,
                                 estimation_robot=robot.name)
    return df


def estimate_run(table: pd.DataFrame, robot: RobotSpec | None = None,
                 preset: str | EkfPreset = "robust") -> pd.DataFrame:
    """Run the EKF, slip and dynamic state over a canonical run table.

    Parameters
    ----------
    table : DataFrame (n_ticks, ...), canonical run table (design §5).
    robot : RobotSpec; None: the spec stored in the table's metadata, else the reference robot.
    preset : ``"robust"`` (default) or ``"thesis"``.

    Returns
    -------
    DataFrame (n_ticks, ...) with the EST columns of contract 2: ``t_s, ekf_*, slip{i}, state{i},
    v_long{i}_mps, nis, nis_dof, estimator_ok, slip_available`` plus pass-through columns
    (wheel omega/current/steer, IMU, every ``*_valid``, ``terrain``, ``run_id``, ``gt_*``).
    """
    return estimate_run_detailed(table, robot, preset)[0]
