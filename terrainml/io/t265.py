"""Intel RealSense T265 frames to robot body axes (design §4, thesis §5.2.3, eq. 5.1-5.10).

Frames
------
``body``        robot frame, x forward, y left, z up (REP-103), origin at the IMU.
``world``       fixed at the robot's start pose, body axes at start (x forward, y left, z up).
``t265_pose``   the T265 tracking (pose) frame, attached to the camera: x right, y up, z backward
                (thesis §5.2.3, found experimentally).
``t265_odom``   the T265's fixed reference ("odom") frame: the ``t265_pose`` frame at power-on
                (origin at the camera's power-on position, same axis convention: x right, y up,
                z backward as the camera faced then).
``t265_imu``    the T265's internal IMU frame: x left, y up, z forward.

The camera is assumed mounted looking forward, level, at ``RobotSpec.camera`` (x_m, y_m, z_m) in
body; a residual mount rotation can be given as ``mount`` (a scipy ``Rotation`` from the
body-aligned camera axes to body axes; identity by default).

T265 odometry message convention (``/camera/odom/sample``, nav_msgs/msg/Odometry)
--------------------------------------------------------------------------------
This is what :func:`body_to_t265_odometry` produces and :func:`t265_odometry_to_body` reads; it is
what librealsense reports (``rs2_pose``) and what the thesis logged:

``pose.pose.position``     camera position in ``t265_odom`` axes (m).
``pose.pose.orientation``  quaternion (x, y, z, w) of the rotation ``t265_pose -> t265_odom``
                           (``R_cam^world`` of eq. 5.3: it maps a vector's ``t265_pose``
                           coordinates to its ``t265_odom`` coordinates).
``twist.twist.linear``     velocity of the camera (mount point) in ``t265_odom`` axes (m/s),
                           i.e. in the *fixed* frame, not the camera frame (thesis §5.2.3).
``twist.twist.angular``    angular velocity of the camera in ``t265_odom`` axes (rad/s).
``pose.covariance[0]``     tracker confidence 0..3 (0 failed, 1 low, 2 medium, 3 high), the
                           convention of :class:`terrainml.io.mcap_writer.RosMcapWriter`.

Ingest (:func:`t265_odometry_to_body`)
--------------------------------------
1. world velocity to camera-local: ``v_local = (R_cam^world)^-1 v_world`` (eq. 5.1-5.3),
   the same for the angular velocity (thesis: "applied uniformly to linear and angular");
2. static axis alignment ``t265_pose -> body`` (x_b = -z_p, y_b = -x_p, z_b = y_p);
3. yaw of the body-aligned orientation ``R_body = A R_cam^world A^T`` (A the static alignment),
   zeroed at the first valid frame (eq. 5.10 applied to yaw).

Ingest stores the **camera-mount velocity in body axes** (lever arm NOT removed; the EKF's
measurement model does that, thesis §5.2.3 and design §7). :func:`robot_velocity_from_mount`
gives the robot-centre velocity (eq. 5.4) when wanted; :func:`robot_position_from_pose` gives the
zeroed robot-centre track (eq. 5.8-5.10).

Departure from the thesis: eq. 5.6 writes the alignment as a left product
``q_robot = q_align (x) q_sensor``. A change of axes of *both* the moving and the fixed frame is a
similarity transform, ``q_body = q_A (x) q_sensor (x) q_A^-1``; the left product alone leaves the
fixed frame in the sensor's axes and mixes yaw with pitch. We use the similarity transform (with
scipy ``Rotation``) and keep ``Q_ALIGN`` = eq. 5.5 (-90 deg about x, then -90 deg about the new z)
as the T265 *IMU* alignment, of which it is exactly the right matrix (``t265_imu -> body`` is
``Q_ALIGN.inv()`` in the active sense, see :data:`IMU_TO_BODY`).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from terrainml.angles import wrap_angle

# eq. 5.5: q_align = q1 (x) q2, q1 = -90 deg about x, q2 = -90 deg about the new (intrinsic) z.
Q_ALIGN = Rotation.from_euler("XZ", [-90.0, -90.0], degrees=True)

# Static axis changes as rotations acting on coordinate vectors: v_body = X_TO_BODY.apply(v_x).
POSE_TO_BODY = Rotation.from_matrix(np.array([[0.0, 0.0, -1.0],    # x_b (fwd)  = -z_pose (backward)
                                              [-1.0, 0.0, 0.0],    # y_b (left) = -x_pose (right)
                                              [0.0, 1.0, 0.0]]))   # z_b (up)   =  y_pose (up)
# v_imu = Q_ALIGN.apply(v_body)  <=>  v_body = Q_ALIGN.inv().apply(v_imu); x_b = z_imu, y_b = x_imu, z_b = y_imu
IMU_TO_BODY = Q_ALIGN.inv()
_POSE_TO_BODY_M = POSE_TO_BODY.as_matrix()



def _as_rot(q_xyzw: np.ndarray) -> Rotation:
    q = np.atleast_2d(np.asarray(q_xyzw, dtype=float))
    return Rotation.from_quat(q)  # scipy order is (x, y, z, w) and it normalises


def imu_to_body(vec_imu: np.ndarray) -> np.ndarray:
    """T265 internal-IMU vectors (n, 3) (x left, y up, z forward) to body axes (n, 3)."""
    return IMU_TO_BODY.apply(np.asarray(vec_imu, dtype=float))


def body_orientation(q_xyzw: np.ndarray, mount: Rotation | None = None) -> Rotation:
    """T265 orientation quaternions (n, 4) (``t265_pose -> t265_odom``) to body orientation.

    Returns the rotations ``body -> world'`` where ``world'`` is the camera's power-on pose with body
    axes (similarity transform with the static alignment, see module docstring).
    """
    a = POSE_TO_BODY if mount is None else mount * POSE_TO_BODY
    return a * _as_rot(q_xyzw) * a.inv()


def t265_odometry_to_body(position_m: np.ndarray, q_xyzw: np.ndarray, linear_mps: np.ndarray,
                          angular_radps: np.ndarray, *, valid: np.ndarray | None = None,
                          mount: Rotation | None = None, positions: bool = True) -> dict[str, np.ndarray]:
    """Map T265 odometry (module docstring convention) to body axes, vectorised over n samples.

    Parameters
    ----------
    position_m : (n, 3) camera position in ``t265_odom`` axes, m.
    q_xyzw : (n, 4) orientation ``t265_pose -> t265_odom``.
    linear_mps : (n, 3) camera velocity in ``t265_odom`` axes, m/s.
    angular_radps : (n, 3) camera angular velocity in ``t265_odom`` axes, rad/s.
    valid : (n,) bool, samples usable for zeroing (first valid frame); all if None.
    mount : optional residual mount rotation (body-aligned camera -> body).
    positions : False: no ``x_m``/``y_m`` (ingest uses velocities and yaw only; saves a third of
        the time of a call on one or two messages, the live aligner's case).

    Returns
    -------
    dict of (n,) arrays: ``vx_mps``, ``vy_mps``, ``vz_mps`` (camera-mount velocity in body axes,
    lever arm not removed), ``yaw_rate_radps`` (about body z), ``yaw_rad`` (zeroed at the first
    valid frame, wrapped), ``yaw_raw_rad``, ``x_m``, ``y_m`` (camera-mount position in the zeroed
    world frame: rotated so the first valid camera pose is at the origin with yaw 0).
    """
    pos = np.atleast_2d(np.asarray(position_m, float))
    lin = np.atleast_2d(np.asarray(linear_mps, float))
    ang = np.atleast_2d(np.asarray(angular_radps, float))
    n = len(pos)
    if n == 0:
        e = np.zeros(0)
        return {k: e for k in ("vx_mps", "vy_mps", "vz_mps", "yaw_rate_radps", "yaw_rad", "yaw_raw_rad",
                               "x_m", "y_m")}
    q = np.atleast_2d(np.asarray(q_xyzw, float))
    qok = np.isfinite(q).all(axis=1) & (np.linalg.norm(np.nan_to_num(q), axis=1) > 1e-9)
    q_safe = np.where(qok[:, None], q, np.array([0.0, 0.0, 0.0, 1.0]))
    m_cw = _as_rot(q_safe).as_matrix()                      # R_cam^world, t265_pose -> t265_odom (eq. 5.3)
    a = POSE_TO_BODY if mount is None else mount * POSE_TO_BODY
    am = _POSE_TO_BODY_M if mount is None else a.as_matrix()
    # eq. 5.1-5.2 (v_local = R^T v_world), then the static alignment: v_body = A R^T v_world
    m_wc = np.swapaxes(m_cw, 1, 2)
    v_body = (m_wc @ lin[:, :, None])[:, :, 0] @ am.T
    w_body = (m_wc @ ang[:, :, None])[:, :, 0] @ am.T
    # body orientation R_b = A R A^T; yaw = atan2(R_b[1,0], R_b[0,0]) (ZYX): row 1 / row 0 of A, column 0 of A^T
    col0 = m_cw @ am[0]                                     # R A^T e0
    yaw_raw = np.where(qok, np.arctan2(col0 @ am[1], col0 @ am[0]), np.nan)
    ok = qok if valid is None else (qok & np.asarray(valid, bool))
    out = {"vx_mps": v_body[:, 0], "vy_mps": v_body[:, 1], "vz_mps": v_body[:, 2],
           "yaw_rate_radps": w_body[:, 2], "yaw_raw_rad": yaw_raw}
    if ok.any():
        k0 = int(np.argmax(ok))
        yaw0 = yaw_raw[k0]
        out["yaw_rad"] = wrap_angle(yaw_raw - yaw0)
        if positions:
            p_world = a.apply(pos)                          # world' axes (body convention)
            p_rel = Rotation.from_euler("z", yaw0).inv().apply(p_world - p_world[k0])   # eq. 5.10, start pose
            out["x_m"], out["y_m"] = p_rel[:, 0], p_rel[:, 1]
    else:
        out["yaw_rad"] = np.full(n, np.nan)
        if positions:
            out["x_m"], out["y_m"] = np.full(n, np.nan), np.full(n, np.nan)
    return out


def robot_velocity_from_mount(vx_mount_mps, vy_mount_mps, yaw_rate_radps,
                              mount_xy_m: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """Robot-centre velocity (body axes) from camera-mount velocity, eq. 5.4 ``v = v_cam - w x d``.

    ``vx = vx_cam + r * y_cam``, ``vy = vy_cam - r * x_cam`` (planar, r = yaw rate).
    """
    dx, dy = float(mount_xy_m[0]), float(mount_xy_m[1])
    r = np.asarray(yaw_rate_radps, float)
    return np.asarray(vx_mount_mps, float) + r * dy, np.asarray(vy_mount_mps, float) - r * dx


def mount_velocity_from_robot(vx_mps, vy_mps, yaw_rate_radps,
                              mount_xy_m: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """Camera-mount velocity (body axes) from robot-centre velocity: ``v + w x d`` (inverse of eq. 5.4)."""
    dx, dy = float(mount_xy_m[0]), float(mount_xy_m[1])
    r = np.asarray(yaw_rate_radps, float)
    return np.asarray(vx_mps, float) - r * dy, np.asarray(vy_mps, float) + r * dx


def robot_position_from_pose(position_m: np.ndarray, q_xyzw: np.ndarray, mount_xyz_m: Sequence[float],
                             *, mount: Rotation | None = None) -> np.ndarray:
    """Robot-centre track (n, 2) in ``world`` from T265 poses, eq. 5.8-5.10.

    ``P_robot = P_cam - R r_body`` (eq. 5.8-5.9, in body-convention axes), then zeroing at the first
    frame ``P_final = P_robot - P_start`` (eq. 5.10) and rotation by the start yaw so that ``world``
    is the robot's start pose (design §4).
    """
    pos = np.atleast_2d(np.asarray(position_m, float))
    a = POSE_TO_BODY if mount is None else mount * POSE_TO_BODY
    r_body = body_orientation(q_xyzw, mount)
    p_cam = a.apply(pos)
    p_robot = p_cam - r_body.apply(np.asarray(mount_xyz_m, float))
    yaw0 = r_body[0].as_euler("ZYX")[0]
    p_final = Rotation.from_euler("z", yaw0).inv().apply(p_robot - p_robot[0])
    return p_final[:, :2]


def body_to_t265_odometry(x_m, y_m, yaw_rad, vx_mps, vy_mps, yaw_rate_radps,
                          mount_xyz_m: Sequence[float], *, start_pose: Sequence[float] = (0.0, 0.0, 0.0),
                          mount: Rotation | None = None) -> dict[str, np.ndarray]:
    """Inverse of the ingest: robot planar state -> T265 odometry message fields (module convention).

    For simulators. The camera is taken as powered on when the robot was at ``start_pose``
    (x, y, yaw in ``world``), so ``t265_odom`` is the camera pose then.

    Parameters
    ----------
    x_m, y_m, yaw_rad : (n,) robot-centre pose in ``world``.
    vx_mps, vy_mps, yaw_rate_radps : (n,) robot-centre velocity in body axes and yaw rate.
    mount_xyz_m : camera mount position in body (``RobotSpec.camera``).

    Returns
    -------
    dict with ``position_m`` (n, 3), ``orientation_xyzw`` (n, 4), ``linear_mps`` (n, 3),
    ``angular_radps`` (n, 3), ready for :meth:`RosMcapWriter.write_camera_odom`.
    """
    x, y, yaw = (np.atleast_1d(np.asarray(v, float)) for v in (x_m, y_m, yaw_rad))
    vx, vy, r = (np.atleast_1d(np.asarray(v, float)) for v in (vx_mps, vy_mps, yaw_rate_radps))
    n = len(x)
    d = np.asarray(mount_xyz_m, float)
    x0, y0, yaw0 = (float(v) for v in start_pose)
    a = POSE_TO_BODY if mount is None else mount * POSE_TO_BODY
    rz = Rotation.from_euler("z", yaw[:, None])
    rz0 = Rotation.from_euler("z", yaw0)
    p_cam_w = np.column_stack([x, y, np.zeros(n)]) + rz.apply(np.tile(d, (n, 1)))
    p_cam0_w = np.array([x0, y0, 0.0]) + rz0.apply(d)
    rel = Rotation.from_euler("z", (yaw - yaw0)[:, None])             # camera (body-aligned) yaw since power-on
    p_t = a.inv().apply(rz0.inv().apply(p_cam_w - p_cam0_w))
    r_cw = a.inv() * rel * a                                # t265_pose -> t265_odom
    vmx, vmy = mount_velocity_from_robot(vx, vy, r, d)
    v_t = a.inv().apply(rel.apply(np.column_stack([vmx, vmy, np.zeros(n)])))
    w_t = a.inv().apply(np.column_stack([np.zeros(n), np.zeros(n), r]))
    return {"position_m": p_t, "orientation_xyzw": r_cw.as_quat(), "linear_mps": v_t, "angular_radps": w_t}
