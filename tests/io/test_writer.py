"""RosMcapWriter's fast CDR encoder writes the same bytes as mcap-ros2's dynamic encoder."""

import numpy as np
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from terrainml.io import cdr, topics
from terrainml.io.mcap_writer import RosMcapWriter, msgdef


def _dynamic(datatype, msg):
    from mcap_ros2._dynamic import serialize_dynamic

    return serialize_dynamic(datatype, msgdef(datatype))[datatype](msg)


def test_encoders_match_the_reference_encoder():
    t_ns = 1_700_000_123_456_789_012
    hdr = {"stamp": {"sec": t_ns // 10**9, "nanosec": t_ns % 10**9}, "frame_id": "imu_link"}
    ref = _dynamic("sensor_msgs/msg/Imu", {
        "header": hdr, "orientation": {"x": 0.1, "y": -0.2, "z": 0.3, "w": 0.9}, "orientation_covariance": [0.0] * 9,
        "angular_velocity": {"x": 1.5, "y": 2.0, "z": -3.0}, "angular_velocity_covariance": [0.0] * 9,
        "linear_acceleration": {"x": 4.0, "y": 5.0, "z": 9.81}, "linear_acceleration_covariance": [0.0] * 9})
    assert cdr.encode_imu(t_ns, b"imu_link", (0.1, -0.2, 0.3, 0.9), (1.5, 2.0, -3.0), (4.0, 5.0, 9.81)) == ref
    for names, pos, vel, eff in [(["wheel1_drive", "wheel2_steer"], [0.0, 0.4], [2.0, 0.0], []),
                                 (["a"], [], [], [5.0]), (["abc", "de", "f"], [1.0, 2.0, 3.0], [], [])]:
        ref = _dynamic("sensor_msgs/msg/JointState", {"header": {**hdr, "frame_id": "base_link"}, "name": names,
                                                      "position": pos, "velocity": vel, "effort": eff})
        assert cdr.encode_joint_state(t_ns, b"base_link", [n.encode() for n in names], pos, vel, eff) == ref
    cov = [0.0] * 36
    cov[0] = 2.0
    ref = _dynamic("nav_msgs/msg/Odometry", {
        "header": {**hdr, "frame_id": "odom"}, "child_frame_id": "camera_pose_frame",
        "pose": {"pose": {"position": {"x": 1.0, "y": 2.0, "z": 3.0}, "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}},
                 "covariance": cov},
        "twist": {"twist": {"linear": {"x": 4.0, "y": 5.0, "z": 6.0}, "angular": {"x": 7.0, "y": 8.0, "z": 9.0}},
                  "covariance": [0.0] * 36}})
    assert cdr.encode_odometry(t_ns, b"odom", b"camera_pose_frame", (1, 2, 3), (0, 0, 0, 1), (4, 5, 6), (7, 8, 9),
                               2.0) == ref


def test_written_log_decodes_with_mcap_ros2(tmp_path):
    path = tmp_path / "w.mcap"
    with RosMcapWriter(path, 2) as w:
        w.write_imu(0.5, (0.1, 0.2, 9.81), (0.0, 0.0, 0.3))
        w.write_wheel_joints(0.5, [1.0, 2.0], [0.1, -0.1])
        w.write_motor_current(0.5, [3.0, 4.0])
        w.write_cmd_vel(0.5, 1.0, 0.0, 0.2)
        w.write_terrain_label(0.5, 7)
        w.write_wheel_state(0.5, [2, 3])
        w.write(topics.IMU, 0.6, {"header": {"stamp": {"sec": 1, "nanosec": 0}, "frame_id": "x"}})  # dict path
    got = {}
    with open(path, "rb") as f:
        for _s, ch, m, msg in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            got.setdefault(ch.topic, []).append(msg)
    assert len(got[topics.IMU]) == 2 and got[topics.IMU][0].linear_acceleration.z == 9.81
    assert list(got[topics.WHEEL_JOINTS][0].name) == ["wheel1_drive", "wheel2_drive", "wheel1_steer", "wheel2_steer"]
    np.testing.assert_allclose(got[topics.WHEEL_JOINTS][0].position, [0, 0, 0.1, -0.1])
    np.testing.assert_allclose(got[topics.MOTOR_CURRENT][0].effort, [3.0, 4.0])
    assert got[topics.CMD_VEL][0].angular.z == 0.2 and got[topics.TERRAIN_LABEL][0].data == 7
    np.testing.assert_allclose(got[topics.SIM_WHEEL_STATE][0].position, [2, 3])
