"""Write a simulated run: ROS 2 MCAP through :class:`terrainml.io.mcap_writer.RosMcapWriter`, or the
canonical run table (SYSTEM §5) directly (Parquet), for speed.

MCAP topics (default topic map, SYSTEM §5): ``/imu`` (100 Hz, IMU axes), ``/camera/odom/sample``
(200 Hz, T265 frames via :func:`terrainml.io.t265.body_to_t265_odometry`, confidence in
pose covariance[0]), ``/wheels/joint_states`` and ``/wheels/motor_current`` (100 Hz), ``/cmd_vel``
(100 Hz), ``/terrain/label`` (on change and every 1 s: class under the body origin), and truth:
``/sim/ground_truth`` (100 Hz, pose in world, twist in body), ``/sim/wheel_slip`` (100 Hz: position =
true SYSTEM §7.1 slip, velocity = true wheel-centre longitudinal speed, effort = true wheel speed),
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
from terrainml.schema import WHEEL_STATES, make_metadata, validate_run_table, write_run_parquet
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


def write_mcap(res: SimResult, path: str | Path, run_id: str | None = None) -> Path:
    """Write the run as a ROS 2 MCAP with the default topic map (see module docstring)."""
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
    acc_i = mount_rot.inv().apply(acc_b)
    gyro_i = mount_rot.inv().apply(gyro_b)
    yaw_imu = res.sensors.imu_yaw(log, len(log))[rows]
    q_imu = (Rotation.from_euler("z", yaw_imu[:, None]) * mount_rot).as_quat()     # IMU axes -> world
    omega = np.column_stack([meas[f"wheel{i}_omega_radps"] for i in range(1, n + 1)])
    steer = np.column_stack([meas[f"wheel{i}_steer_rad"] for i in range(1, n + 1)])
    cur = np.column_stack([meas[f"wheel{i}_current_a"] for i in range(1, n + 1)])
    slip = res.true_slip()[rows]
    v_long = res.wblock("v_long")[rows]
    om_true = res.wblock("omega")[rows]
    states = res.true_states(rows)
    label = res.class_under_robot(rows)
    cam_rows = np.arange(len(log))
    cam = camera_messages(res, cam_rows) if rb.camera is not None else None
    t_all = log[:, ph.L_T]
    cmd = res.cmd
    with RosMcapWriter(path, n, metadata=run_metadata(res, run_id)) as w:
        last_label, last_label_t = None, -np.inf
        for k in range(len(log)):
            t = float(t_all[k])
            if cam is not None:
                w.write_camera_odom(t, cam["position_m"][k], cam["orientation_xyzw"][k], cam["linear_mps"][k],
                                    cam["angular_radps"][k], confidence=float(cam["confidence"][k]))
            if k % 2:
                continue
            j = k // 2
            w.write_imu(t, acc_i[j], gyro_i[j], q_imu[j])
            w.write_wheel_joints(t, omega[j], steer[j])
            w.write_motor_current(t, cur[j])
            c = cmd[min(j, len(cmd) - 1)] if len(cmd) else (0.0, 0.0, 0.0)
            w.write_cmd_vel(t, c[0], c[1], c[2])
            w.write_ground_truth(t, log[k, ph.L_X], log[k, ph.L_Y], log[k, ph.L_PSI], log[k, ph.L_VX],
                                 log[k, ph.L_VY], log[k, ph.L_R])
            w.write_wheel_slip(t, slip[j], v_long[j], om_true[j])
            w.write_wheel_state(t, states[j])
            if label[j] != last_label or t - last_label_t >= 1.0 - 1e-9:
                w.write_terrain_label(t, int(label[j]))
                last_label, last_label_t = label[j], t
    return path


def run_table(res: SimResult, run_id: str = "sim") -> pd.DataFrame:
    """Canonical run table at 100 Hz (SYSTEM §5) straight from the simulator, with truth columns.

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
            data[f"wheel{i + 1}_cmd_omega_radps"] = res.omega_cmd[idx, i]
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
