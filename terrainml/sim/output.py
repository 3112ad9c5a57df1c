"""Write a simulated run: ROS 2 MCAP through :class:`terrainml.io.mcap_writer.RosMcapWriter`, or the
canonical run table (design §5) directly (Parquet), for speed.

MCAP topics (default topic map, design §5): ``/imu`` (100 Hz, IMU axes), ``/camera/odom/sample``
(200 Hz, T265 frames via :func:`terrainml.io.t265.body_to_t265_odometry`, confidence in
pose covariance[0]), ``/wheels/joint_states`` and ``/wheels/motor_current`` (100 Hz), ``/cmd_vel``
(100 Hz), ``/terrain/label`` (on change and every 1 s: class under the body origin), and truth:
``/sim/ground_truth`` (100 Hz, pose in world, twist in body), ``/sim/wheel_slip`` (100 Hz: position =
true design §7.1 slip, velocity = true wheel-centre longitudinal speed, effort = true wheel speed),
``/sim/wheel_state`` (100 Hz, §7.2 state codes from true acceleration).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from terrainml.io import t265
from terrainml.io.mcap_writer import RosMcapWriter
from terrainml.schema import WHEEL_STATES, make_metadata, validate_run_table, wheel_col, write_run_parquet
from terrainml.sim import physics as ph
from terrainml.sim.simulator import SimResult, sample_dict


def _rows100(res: SimResult) -> np.ndarray:
    return np.arange(0, len(res.log), 2)


def run_metadata(res: SimResult, run_id: str) -> dict[str, str]:
    sc = res.scenario
    return {
        "run_id": run_id, "scenario": sc.name, "seed": str(res.seed),
        "terrain": ",".join(str(int(c)) for c in res.terrain.layout.grid.reshape(-1)),
        "duration_s": f"{sc.duration_s:g}", "robot": res.robot.name, "robot_sha256": res.robot.sha256(),
        "energy_j": f"{res.energy_j:.3f}", "distance_m": f"{res.distance_m:.3f}",
        "stuck_events": str(res.stuck_events), "generator": "terrainml.sim",
        "scenario_info": json.dumps(sc.info, default=str),
    }


def camera_messages(res: SimResult, rows: np.ndarray) -> dict[str, np.ndarray]:
    """T265 odometry fields for 200 Hz ``rows`` (noisy mount velocity, T265 frames)."""
    cam = res.robot.camera
    mount = (cam.x_m, cam.y_m, cam.z_m)
    vx, vy, r, yaw, conf = res.sensors.cam_robot_centre(res.log, rows, (cam.x_m, cam.y_m))
    src = res.sensors.cam_rows(rows)
    msg = t265.body_to_t265_odometry(res.log[src, ph.L_X], res.log[src, ph.L_Y], yaw, vx, vy, r, mount)
    msg["confidence"] = conf
    return msg


def label_rows(t_s: np.ndarray, label: np.ndarray, period_s: float = 1.0) -> np.ndarray:
    """Rows of the ``/terrain/label`` messages: each change of class, and otherwise ``period_s`` after
    the previous message (the rule a per-row loop applies: new class, or ``t - t_last >= period``)."""
    change = np.flatnonzero(np.r_[True, label[1:] != label[:-1]])
    rows: list[int] = []
    for c in np.r_[change, len(t_s)]:
        while rows:            # periodic repeats between the last message and the next change
            r = rows[-1]
            due = np.flatnonzero(t_s[r + 1:c] - t_s[r] >= period_s - 1e-9)
            if not len(due):
                break
            rows.append(r + 1 + int(due[0]))
        if c < len(t_s):
            rows.append(int(c))
    return np.asarray(rows, np.int64)


def write_mcap(res: SimResult, path: str | Path, run_id: str | None = None, block_s: float = 2.0) -> Path:
    """Write the run as a ROS 2 MCAP with the default topic map (see module docstring).

    Messages are encoded ``block_s`` of simulated time at a time (one block per topic, one MCAP chunk
    per block of time), the messages of each topic in time order.
    """
    path = Path(path)
    run_id = run_id or path.stem
    rb = res.robot
    n = rb.n_wheels
    log = res.log
    rows = _rows100(res)
    meas = sample_dict(res, log, rows, rb)
    acc_b = np.column_stack([meas["imu_ax_mps2"], meas["imu_ay_mps2"], meas["imu_az_mps2"]])
    _, gyro_b = res.sensors.imu(log, rows)
    gyro_b[:, 2] = meas["imu_yaw_rate_radps"]
    mount_rot = Rotation.from_euler("xyz", [rb.imu.roll_rad, rb.imu.pitch_rad, rb.imu.yaw_rad])
    yaw_imu = res.sensors.imu_yaw(log, len(log))[rows]
    t_all = log[:, ph.L_T]
    cmd = res.cmd
    m = len(rows)
    cmd_rows = cmd[np.minimum(np.arange(m), len(cmd) - 1)] if len(cmd) else np.zeros((m, 3))
    gt = log[rows]
    per_100hz = {   # (m, ...) columns of the 100 Hz messages, sliced per block below
        "t": t_all[rows], "acc": mount_rot.inv().apply(acc_b), "gyro": mount_rot.inv().apply(gyro_b),
        "q": (Rotation.from_euler("z", yaw_imu[:, None]) * mount_rot).as_quat(),     # IMU axes -> world
        "omega": np.column_stack([meas[wheel_col("omega", i)] for i in range(1, n + 1)]),
        "steer": np.column_stack([meas[wheel_col("steer", i)] for i in range(1, n + 1)]),
        "cur": np.column_stack([meas[wheel_col("current", i)] for i in range(1, n + 1)]),
        "cmd": cmd_rows, "slip": res.true_slip()[rows], "v_long": res.wblock("v_long")[rows],
        "om_true": res.wblock("omega")[rows], "states": res.true_states(rows),
    }
    label = res.class_under_robot(rows)
    lab = label_rows(per_100hz["t"], label)
    cam = camera_messages(res, np.arange(len(log))) if rb.camera is not None else None
    step = max(int(round(block_s * 100.0)), 1)          # 100 Hz rows per block
    with RosMcapWriter(path, n, metadata=run_metadata(res, run_id)) as w:
        for a in range(0, m, step):
            b = min(a + step, m)
            if cam is not None:       # the 200 Hz rows of this block: up to the next block's first
                ka, kb = rows[a], (rows[b] if b < m else len(log))
                c = {k: v[ka:kb] for k, v in cam.items()}
                w.write_camera_odom(t_all[ka:kb], c["position_m"], c["orientation_xyzw"], c["linear_mps"],
                                    c["angular_radps"], confidence=c["confidence"])
            d = {k: v[a:b] for k, v in per_100hz.items()}
            t = d["t"]
            w.write_imu(t, d["acc"], d["gyro"], d["q"])
            w.write_wheel_joints(t, d["omega"], d["steer"])
            w.write_motor_current(t, d["cur"])
            w.write_cmd_vel(t, d["cmd"][:, 0], d["cmd"][:, 1], d["cmd"][:, 2])
            g = gt[a:b]
            w.write_ground_truth(t, g[:, ph.L_X], g[:, ph.L_Y], g[:, ph.L_PSI], g[:, ph.L_VX], g[:, ph.L_VY],
                                 g[:, ph.L_R])
            w.write_wheel_slip(t, d["slip"], d["v_long"], d["om_true"])
            w.write_wheel_state(t, d["states"])
            la = lab[(lab >= a) & (lab < b)]
            if len(la):
                w.write_terrain_label(per_100hz["t"][la], label[la])
            w.flush()
    return path


def run_table(res: SimResult, run_id: str = "sim") -> pd.DataFrame:
    """Canonical run table at 100 Hz (design §5) straight from the simulator, with truth columns.

    Camera columns are the mount velocity in body axes (what ingest produces), ``cam_valid`` is
    confidence >= 2 (ingest's default), IMU yaw is integrated from the measured gyro.
    """
    rb = res.robot
    n = rb.n_wheels
    log = res.log
    rows = _rows100(res)
    data = sample_dict(res, log, rows, rb)
    data["imu_yaw_rad"] = res.sensors.imu_yaw(log, len(log))[rows]
    m = len(rows)
    cmd = res.cmd
    idx = np.minimum(np.arange(m), max(len(cmd) - 1, 0))
    if len(cmd):
        data["cmd_vx_mps"], data["cmd_vy_mps"], data["cmd_yaw_rate_radps"] = cmd[idx, 0], cmd[idx, 1], cmd[idx, 2]
        for i in range(n):
            data[wheel_col("cmd_omega", i + 1)] = res.omega_cmd[idx, i]
    data["terrain"] = res.class_under_robot(rows).astype(np.int64)
    data["run_id"] = np.full(m, run_id, dtype=object)
    data["gt_vx_mps"], data["gt_vy_mps"] = log[rows, ph.L_VX], log[rows, ph.L_VY]
    data["gt_yaw_rate_radps"] = log[rows, ph.L_R]
    data["gt_x_m"], data["gt_y_m"], data["gt_yaw_rad"] = log[rows, ph.L_X], log[rows, ph.L_Y], log[rows, ph.L_PSI]
    slip = res.true_slip()[rows]
    states = res.true_states(rows)
    for i in range(n):
        data[f"gt_slip{i + 1}"] = slip[:, i]
        data[f"gt_state{i + 1}"] = np.array(WHEEL_STATES, dtype=object)[states[:, i]]
    df = pd.DataFrame(data)
    if "cam_confidence" in df:
        df["cam_valid"] = df["cam_confidence"].to_numpy() >= 2
    df = validate_run_table(df, n_wheels=n, source=run_id)
    df.attrs["terrainml"] = make_metadata(robot_json=rb.to_json(), source_file=None, rate_hz=100.0,
                                          run=run_metadata(res, run_id))
    return df


def write_parquet(res: SimResult, path: str | Path, run_id: str | None = None) -> Path:
    path = Path(path)
    df = run_table(res, run_id or path.stem)
    return write_run_parquet(df, path)
