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
        "pose": {"pose": {"position": {"x": 1.0, "y": 2.0, "z": 3.0},
                          "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}},
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


# ----------------------------------------------------------------------------- block encoding
def _hdr(t_ns, frame_id):
    return {"stamp": {"sec": int(t_ns) // 10**9, "nanosec": int(t_ns) % 10**9}, "frame_id": frame_id}


def _xyz(v):
    return {"x": float(v[0]), "y": float(v[1]), "z": float(v[2])}


def _xyzw(q):
    return {**_xyz(q), "w": float(q[3])}


def test_block_encoders_match_the_reference_encoder_row_by_row():
    """Every row of a block equals mcap-ros2's dynamic encoder on that row's message dict."""
    rng = np.random.default_rng(18)
    n = 6
    t_ns = 1_700_000_000_000_000_000 + rng.integers(0, 10**12, n)
    q, gyro, acc = rng.normal(size=(n, 4)), rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    imu = cdr.encode_imu_block(t_ns, b"imu_link", q, gyro, acc)
    for i in range(n):
        assert imu[i].tobytes() == _dynamic("sensor_msgs/msg/Imu", {
            "header": _hdr(t_ns[i], "imu_link"), "orientation": _xyzw(q[i]), "orientation_covariance": [0.0] * 9,
            "angular_velocity": _xyz(gyro[i]), "angular_velocity_covariance": [0.0] * 9,
            "linear_acceleration": _xyz(acc[i]), "linear_acceleration_covariance": [0.0] * 9})
    pos, lin, ang, conf = (rng.normal(size=(n, 3)), rng.normal(size=(n, 3)), rng.normal(size=(n, 3)),
                           rng.uniform(0, 3, n))
    odo = cdr.encode_odometry_block(t_ns, b"camera_odom_frame", b"camera_pose_frame", pos, q, lin, ang, conf)
    for i in range(n):
        cov = [0.0] * 36
        cov[0] = float(conf[i])
        assert odo[i].tobytes() == _dynamic("nav_msgs/msg/Odometry", {
            "header": _hdr(t_ns[i], "camera_odom_frame"), "child_frame_id": "camera_pose_frame",
            "pose": {"pose": {"position": _xyz(pos[i]), "orientation": _xyzw(q[i])}, "covariance": cov},
            "twist": {"twist": {"linear": _xyz(lin[i]), "angular": _xyz(ang[i])}, "covariance": [0.0] * 36}})
    for names, fields in [(["wheel1_drive", "wheel2_drive", "wheel1_steer"], ("position", "velocity")),
                          (["w1", "w22", "w333", "w4"], ("effort",)), (["abc"], ("position", "velocity", "effort")),
                          (["wheel1", "wheel2"], ())]:
        vals = {f: rng.normal(size=(n, len(names))) for f in fields}
        js = cdr.encode_joint_state_block(t_ns, b"base_link", [s.encode() for s in names], **vals)
        for i in range(n):
            assert js[i].tobytes() == _dynamic("sensor_msgs/msg/JointState", {
                "header": _hdr(t_ns[i], "base_link"), "name": names,
                **{f: (vals[f][i].tolist() if f in vals else []) for f in ("position", "velocity", "effort")}})
    tw = cdr.encode_twist_block(lin, ang)
    for i in range(n):
        assert tw[i].tobytes() == _dynamic("geometry_msgs/msg/Twist", {"linear": _xyz(lin[i]),
                                                                        "angular": _xyz(ang[i])})
    labels = np.array([0, 7, 255, 3, 1, 2])
    u8 = cdr.encode_uint8_block(labels)
    for i in range(n):
        assert u8[i].tobytes() == _dynamic("std_msgs/msg/UInt8", {"data": int(labels[i])})


def _messages(path):
    """Per topic: (log time, sequence, raw data, mcap-ros2-decoded message), in file order."""
    got = {}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _s, ch, m, msg in reader.iter_decoded_messages(log_time_order=False):
            got.setdefault(ch.topic, []).append((m.log_time, m.sequence, m.data, msg))
    return got


def test_block_writes_equal_message_by_message_writes(tmp_path):
    """The same messages written as blocks and one at a time give the same (time, sequence, bytes) per
    topic, decodable by mcap-ros2; small chunks split a block where one-at-a-time writes would."""
    rng = np.random.default_rng(3)
    n, k = 250, 3
    t = np.arange(n) / 100.0
    acc, gyro, q = rng.normal(size=(n, 3)), rng.normal(size=(n, 3)), rng.normal(size=(n, 4))
    om, st, cur = rng.normal(size=(n, k)), rng.normal(size=(n, k)), rng.normal(size=(n, k))
    cmd, gt = rng.normal(size=(n, 3)), rng.normal(size=(n, 6))
    states, labels = rng.integers(0, 4, (n, k)), rng.integers(0, 8, n)
    pos, lin, ang = rng.normal(size=(n, 3)), rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    conf = rng.uniform(0, 3, n)
    one, block = tmp_path / "one.mcap", tmp_path / "block.mcap"
    with RosMcapWriter(one, k, chunk_size=8 * 1024) as w:
        for i in range(n):
            w.write_camera_odom(t[i], pos[i], q[i], lin[i], ang[i], confidence=conf[i])
            w.write_imu(t[i], acc[i], gyro[i], q[i])
            w.write_wheel_joints(t[i], om[i], st[i])
            w.write_motor_current(t[i], cur[i])
            w.write_cmd_vel(t[i], *cmd[i])
            w.write_ground_truth(t[i], *gt[i])
            w.write_wheel_slip(t[i], om[i], st[i], cur[i])
            w.write_wheel_state(t[i], states[i])
            w.write_terrain_label(t[i], labels[i])
    with RosMcapWriter(block, k, chunk_size=8 * 1024) as w:
        for a in (slice(0, 100), slice(100, n)):
            w.write_camera_odom(t[a], pos[a], q[a], lin[a], ang[a], confidence=conf[a])
            w.write_imu(t[a], acc[a], gyro[a], q[a])
            w.write_wheel_joints(t[a], om[a], st[a])
            w.write_motor_current(t[a], cur[a])
            w.write_cmd_vel(t[a], cmd[a, 0], cmd[a, 1], cmd[a, 2])
            w.write_ground_truth(t[a], *gt[a].T)
            w.write_wheel_slip(t[a], om[a], st[a], cur[a])
            w.write_wheel_state(t[a], states[a])
            w.write_terrain_label(t[a], labels[a])
            w.flush()
    a, b = _messages(one), _messages(block)
    assert a.keys() == b.keys() and len(a) == 9
    for topic in a:
        assert [m[:3] for m in a[topic]] == [m[:3] for m in b[topic]], topic
        assert [m[1] for m in b[topic]] == list(range(n))
    np.testing.assert_array_equal([m[3].linear_acceleration.y for m in b[topics.IMU]], acc[:, 1])
    np.testing.assert_array_equal([m[3].effort[2] for m in b[topics.MOTOR_CURRENT]], cur[:, 2])
    np.testing.assert_array_equal([m[3].data for m in b[topics.TERRAIN_LABEL]], labels)
    with open(block, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary.statistics.message_count == 9 * n and len(summary.chunk_indexes) > 4
    assert all(c.uncompressed_size <= 8 * 1024 + 800 for c in summary.chunk_indexes)
    assert set(summary.statistics.channel_message_counts.values()) == {n}
