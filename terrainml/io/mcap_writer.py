"""Write ROS 2 MCAP logs (CDR) with the standard messages of the default topic map (SYSTEM §5).

The simulator writes through this class, so the ingest path is exercised on real ROS 2 encoding.
Message definitions come from rosbags' ROS 2 Humble type store. The typed ``write_*`` methods encode
with :mod:`terrainml.io.cdr`'s fixed-layout CDR encoder (byte-identical to mcap-ros2-support's
dynamic encoder, tested, and several times faster); the generic :meth:`RosMcapWriter.write` of a
message dict uses mcap-ros2-support's encoder.

Message conventions (documented for users reproducing them on a robot)
------------------------------------------------------------------------
``/wheels/joint_states``  sensor_msgs/msg/JointState: names ``wheel{i}_drive`` (velocity = wheel
                          angular speed, rad/s) and ``wheel{i}_steer`` (position = steering angle, rad).
``/wheels/motor_current`` sensor_msgs/msg/JointState: names ``wheel{i}_drive``; the *effort* field
                          holds the motor current in A (positive when driving forward).
``/camera/odom/sample``   nav_msgs/msg/Odometry in the T265's own frames (pose frame x right, y up,
                          z backward; twist.linear in the pose frame, as the realsense driver
                          publishes it); covariance[0] carries the tracker confidence 0..3.
``/sim/wheel_slip``       sensor_msgs/msg/JointState: names ``wheel{i}``; position = true slip
                          (SYSTEM §7.1), velocity = true longitudinal wheel-centre speed (m/s),
                          effort = true wheel angular speed (rad/s).
``/sim/wheel_state``      sensor_msgs/msg/JointState: names ``wheel{i}``; position = state code
                          (0 idle, 1 steady, 2 traction, 3 braking).
``/sim/ground_truth``     nav_msgs/msg/Odometry: pose in ``world``, twist in ``body``.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Sequence

from mcap_ros2.writer import Writer
from rosbags.typesys import Stores, get_typestore

from terrainml.io import cdr, topics

_ZERO9 = [0.0] * 9
_ZERO36 = [0.0] * 36


def msgdef(datatype: str) -> str:
    """Concatenated ROS 2 message definition text for ``datatype`` (e.g. sensor_msgs/msg/Imu)."""
    text, _ = get_typestore(Stores.ROS2_HUMBLE).generate_msgdef(datatype, ros_version=2)
    return text


def _stamp(t_ns: int) -> dict:
    return {"sec": int(t_ns // 1_000_000_000), "nanosec": int(t_ns % 1_000_000_000)}


def _header(t_ns: int, frame_id: str) -> dict:
    return {"stamp": _stamp(t_ns), "frame_id": frame_id}


class RosMcapWriter:
    """Typed writer for the default topic map; use as a context manager.

    Parameters
    ----------
    path : output ``.mcap`` file.
    n_wheels : number of wheels (joint names ``wheel{i}_drive``/``wheel{i}_steer``).
    start_time_ns : UNIX time of t = 0; message times are ``start_time_ns + t_s * 1e9``.
    topic_names : optional override of default topic names, keyed by the defaults in
        :mod:`terrainml.io.topics`.
    metadata : optional string key-value metadata written as an MCAP metadata record ``terrainml``.
    """

    def __init__(self, path: str | Path, n_wheels: int, *, start_time_ns: int = 1_700_000_000_000_000_000,
                 topic_names: dict[str, str] | None = None, metadata: dict[str, str] | None = None,
                 chunk_size: int = 1024 * 1024):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.n_wheels = int(n_wheels)
        self.t0_ns = int(start_time_ns)
        self._names = dict(topic_names or {})
        self._file = open(self.path, "wb")
        self._writer = Writer(self._file, chunk_size=chunk_size)
        self._schemas: dict[str, object] = {}
        self._seq: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._drive_names = [f"wheel{i}_drive" for i in range(1, self.n_wheels + 1)]
        self._steer_names = [f"wheel{i}_steer" for i in range(1, self.n_wheels + 1)]
        self._truth_names = [f"wheel{i}" for i in range(1, self.n_wheels + 1)]
        self._drive_names_b = [n.encode() for n in self._drive_names]
        self._joint_names_b = [n.encode() for n in self._drive_names + self._steer_names]
        self._truth_names_b = [n.encode() for n in self._truth_names]
        if metadata:
            self._writer.add_metadata("terrainml", {str(k): str(v) for k, v in metadata.items()})

    # ------------------------------------------------------------------ plumbing
    def __enter__(self) -> "RosMcapWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        if not self._file.closed:
            self._writer.finish()
            self._file.close()

    def _t_ns(self, t_s: float) -> int:
        return self.t0_ns + int(round(t_s * 1e9))

    def _schema(self, datatype: str):
        schema = self._schemas.get(datatype)
        if schema is None:
            schema = self._schemas[datatype] = self._writer.register_msgdef(datatype, msgdef(datatype))
        return schema

    def write(self, default_topic: str, t_s: float, message: dict, datatype: str | None = None) -> None:
        """Write one message dict on a (possibly remapped) topic at time ``t_s``."""
        topic = self._names.get(default_topic, default_topic)
        datatype = datatype or topics.MESSAGE_TYPES[default_topic]
        schema = self._schema(datatype)
        t_ns = self._t_ns(t_s)
        seq = self._seq.get(topic, 0)
        self._seq[topic] = seq + 1
        self._writer.write_message(topic, schema, message, log_time=t_ns, publish_time=t_ns, sequence=seq)

    def _write_cdr(self, default_topic: str, t_ns: int, data: bytes) -> None:
        """Write already CDR-encoded bytes of the default type of ``default_topic``."""
        topic = self._names.get(default_topic, default_topic)
        cid = self._channels.get(topic)
        if cid is None:
            schema = self._schema(topics.MESSAGE_TYPES[default_topic])
            ids = self._writer._channel_ids  # share channels with the dict path (mcap-ros2 Writer)
            cid = ids.get(topic)
            if cid is None:
                cid = ids[topic] = self._writer._writer.register_channel(
                    topic=topic, message_encoding="cdr", schema_id=schema.id)
            self._channels[topic] = cid
        seq = self._seq.get(topic, 0)
        self._seq[topic] = seq + 1
        self._writer._writer.add_message(channel_id=cid, log_time=t_ns, publish_time=t_ns, sequence=seq, data=data)

    # ------------------------------------------------------------------ typed messages
    def write_imu(self, t_s: float, accel_mps2: Sequence[float], gyro_radps: Sequence[float],
                  orientation_xyzw: Sequence[float] = (0.0, 0.0, 0.0, 1.0), frame_id: str = "imu_link") -> None:
        """sensor_msgs/Imu in the IMU's own axes (the topic map's mount rotation maps them to body)."""
        t_ns = self._t_ns(t_s)
        self._write_cdr(topics.IMU, t_ns, cdr.encode_imu(
            t_ns, frame_id.encode(), [float(v) for v in orientation_xyzw], [float(v) for v in gyro_radps],
            [float(v) for v in accel_mps2]))

    def write_odometry(self, default_topic: str, t_s: float, position_m: Sequence[float],
                       orientation_xyzw: Sequence[float], linear_mps: Sequence[float],
                       angular_radps: Sequence[float], *, frame_id: str, child_frame_id: str,
                       confidence: float | None = None) -> None:
        """nav_msgs/Odometry; ``confidence`` (if given) is stored in pose covariance[0]."""
        t_ns = self._t_ns(t_s)
        self._write_cdr(default_topic, t_ns, cdr.encode_odometry(
            t_ns, frame_id.encode(), child_frame_id.encode(), [float(v) for v in position_m],
            [float(v) for v in orientation_xyzw], [float(v) for v in linear_mps],
            [float(v) for v in angular_radps], 0.0 if confidence is None else float(confidence)))

    def write_camera_odom(self, t_s: float, position_m, orientation_xyzw, linear_mps, angular_radps,
                          confidence: float = 3.0) -> None:
        """T265 odometry in its own pose frame (x right, y up, z backward)."""
        self.write_odometry(topics.CAMERA_ODOM, t_s, position_m, orientation_xyzw, linear_mps, angular_radps,
                            frame_id="camera_odom_frame", child_frame_id="camera_pose_frame",
                            confidence=confidence)

    def write_wheel_joints(self, t_s: float, omega_radps: Sequence[float], steer_rad: Sequence[float]) -> None:
        n = self.n_wheels
        t_ns = self._t_ns(t_s)
        self._write_cdr(topics.WHEEL_JOINTS, t_ns, cdr.encode_joint_state(
            t_ns, b"base_link", self._joint_names_b, [0.0] * n + [float(v) for v in steer_rad],
            [float(v) for v in omega_radps] + [0.0] * n, ()))

    def write_motor_current(self, t_s: float, current_a: Sequence[float]) -> None:
        t_ns = self._t_ns(t_s)
        self._write_cdr(topics.MOTOR_CURRENT, t_ns, cdr.encode_joint_state(
            t_ns, b"base_link", self._drive_names_b, (), (), [float(v) for v in current_a]))

    def write_cmd_vel(self, t_s: float, vx_mps: float, vy_mps: float, yaw_rate_radps: float) -> None:
        self._write_cdr(topics.CMD_VEL, self._t_ns(t_s), cdr.encode_twist(
            (float(vx_mps), float(vy_mps), 0.0), (0.0, 0.0, float(yaw_rate_radps))))

    def write_terrain_label(self, t_s: float, class_id: int) -> None:
        self._write_cdr(topics.TERRAIN_LABEL, self._t_ns(t_s), cdr.encode_uint8(int(class_id)))

    def write_ground_truth(self, t_s: float, x_m: float, y_m: float, yaw_rad: float,
                           vx_mps: float, vy_mps: float, yaw_rate_radps: float) -> None:
        half = 0.5 * yaw_rad
        self.write_odometry(topics.SIM_GROUND_TRUTH, t_s, (x_m, y_m, 0.0),
                            (0.0, 0.0, math.sin(half), math.cos(half)),
                            (vx_mps, vy_mps, 0.0), (0.0, 0.0, yaw_rate_radps),
                            frame_id="world", child_frame_id="base_link")

    def write_wheel_slip(self, t_s: float, slip: Sequence[float], v_long_mps: Sequence[float],
                         omega_radps: Sequence[float]) -> None:
        t_ns = self._t_ns(t_s)
        self._write_cdr(topics.SIM_WHEEL_SLIP, t_ns, cdr.encode_joint_state(
            t_ns, b"base_link", self._truth_names_b, [float(v) for v in slip], [float(v) for v in v_long_mps],
            [float(v) for v in omega_radps]))

    def write_wheel_state(self, t_s: float, state_codes: Sequence[int]) -> None:
        t_ns = self._t_ns(t_s)
        self._write_cdr(topics.SIM_WHEEL_STATE, t_ns, cdr.encode_joint_state(
            t_ns, b"base_link", self._truth_names_b, [float(v) for v in state_codes], (), ()))
