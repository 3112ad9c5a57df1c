"""Block-encoded simulator MCAP: every message is what mcap-ros2's own encoder writes for
it, carries the simulator's values, and does not depend on the block size."""

from __future__ import annotations

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2._dynamic import serialize_dynamic
from mcap_ros2.decoder import DecoderFactory

from terrainml.io import topics
from terrainml.io.ingest import load_run
from terrainml.sim import physics as ph
from terrainml.sim.generate import simulate
from terrainml.sim.output import run_table, write_mcap

T0_NS = 1_700_000_000_000_000_000    # RosMcapWriter's default start time


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A 6 s run over three terrains (label changes and 1 s repeats), written in odd-sized blocks."""
    res = simulate(0, "mixed", speed_mps=1.0, duration_s=6.0, seed=4,
                   terrains=["pavement", "dry_sand", "short_grass"], segment_m=1.5)
    d = tmp_path_factory.mktemp("blocks")
    return res, write_mcap(res, d / "odd.mcap", block_s=0.37), write_mcap(res, d / "default.mcap")


def _read(path):
    """Per topic: [(log time, sequence, data, decoded message, schema)] in file order."""
    out = {}
    with open(path, "rb") as f:
        for schema, ch, m, msg in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages(
                log_time_order=False):
            out.setdefault(ch.topic, []).append((m.log_time, m.sequence, m.data, msg, schema))
    return out


def test_every_message_is_what_the_reference_encoder_writes(run):
    _, path, _ = run
    encoders = {}
    types = set()
    for msgs in _read(path).values():
        for _, _, data, msg, schema in msgs:
            enc = encoders.get(schema.name)
            if enc is None:
                enc = encoders[schema.name] = serialize_dynamic(schema.name, schema.data.decode())[schema.name]
            assert enc(msg) == data, schema.name
            types.add(schema.name)
    assert types == {"sensor_msgs/msg/Imu", "nav_msgs/msg/Odometry", "sensor_msgs/msg/JointState",
                     "geometry_msgs/msg/Twist", "std_msgs/msg/UInt8"}


def test_messages_carry_the_simulator_values(run):
    res, path, _ = run
    got = _read(path)
    rows = np.arange(0, len(res.log), 2)
    t100 = res.log[rows, ph.L_T]
    for topic, msgs in got.items():
        assert [m[1] for m in msgs] == list(range(len(msgs))), topic      # sequences count per topic
    assert len(got[topics.CAMERA_ODOM]) == len(res.log)
    np.testing.assert_array_equal([m[0] for m in got[topics.CAMERA_ODOM]],
                                  T0_NS + np.rint(res.log[:, ph.L_T] * 1e9).astype(np.int64))
    for topic in (topics.IMU, topics.WHEEL_JOINTS, topics.MOTOR_CURRENT, topics.CMD_VEL, topics.SIM_GROUND_TRUTH,
                  topics.SIM_WHEEL_SLIP, topics.SIM_WHEEL_STATE):
        np.testing.assert_array_equal([m[0] for m in got[topic]], T0_NS + np.rint(t100 * 1e9).astype(np.int64))
    stamps = [m[3].header.stamp.sec * 10**9 + m[3].header.stamp.nanosec for m in got[topics.IMU]]
    np.testing.assert_array_equal(stamps, [m[0] for m in got[topics.IMU]])
    gt = [m[3] for m in got[topics.SIM_GROUND_TRUTH]]
    np.testing.assert_array_equal([g.pose.pose.position.x for g in gt], res.log[rows, ph.L_X])
    np.testing.assert_array_equal([g.twist.twist.linear.x for g in gt], res.log[rows, ph.L_VX])
    np.testing.assert_array_equal([g.twist.twist.angular.z for g in gt], res.log[rows, ph.L_R])
    yaw = [2 * np.arctan2(g.pose.pose.orientation.z, g.pose.pose.orientation.w) for g in gt]
    np.testing.assert_allclose(np.unwrap(yaw), np.unwrap(res.log[rows, ph.L_PSI]), atol=1e-12)
    cmd = res.cmd[np.minimum(np.arange(len(rows)), len(res.cmd) - 1)]
    np.testing.assert_array_equal([m[3].linear.x for m in got[topics.CMD_VEL]], cmd[:, 0])
    np.testing.assert_array_equal([m[3].angular.z for m in got[topics.CMD_VEL]], cmd[:, 2])
    np.testing.assert_array_equal([m[3].position for m in got[topics.SIM_WHEEL_SLIP]], res.true_slip()[rows])
    np.testing.assert_array_equal([m[3].position for m in got[topics.SIM_WHEEL_STATE]], res.true_states(rows))
    # /terrain/label: on each change of class and 1 s after the previous label (a per-row loop here)
    label = res.class_under_robot(rows)
    want, last, last_t = [], None, -np.inf
    for j, t in enumerate(t100):
        if label[j] != last or t - last_t >= 1.0 - 1e-9:
            want.append((T0_NS + int(round(t * 1e9)), int(label[j])))
            last, last_t = label[j], t
    assert [(m[0], m[3].data) for m in got[topics.TERRAIN_LABEL]] == want
    assert len({w[1] for w in want}) >= 2 and len(want) >= 5       # changes and repeats both occur


def test_block_size_does_not_change_the_messages(run):
    _, odd, default = run
    a, b = _read(odd), _read(default)
    assert a.keys() == b.keys()
    for topic in a:
        assert [m[:3] for m in a[topic]] == [m[:3] for m in b[topic]], topic
    with open(odd, "rb") as f:
        chunks = sorted((c.message_start_time, c.message_end_time) for c in make_reader(f).get_summary().chunk_indexes)
    assert len(chunks) >= 16
    assert all(e0 < s1 for (_, e0), (s1, _) in zip(chunks, chunks[1:]))   # one chunk per block of time


def test_ingest_round_trip(run):
    res, path, _ = run
    t = load_run(path, robot=res.robot).table
    direct = run_table(res, "odd")
    assert len(t) == len(direct)
    for col in ("gt_vx_mps", "gt_x_m", "gt_slip2", "wheel3_omega_radps", "imu_ax_mps2", "cam_vx_mps", "terrain"):
        np.testing.assert_allclose(t[col].to_numpy(float), direct[col].to_numpy(float), atol=1e-9, err_msg=col)
    assert (t["gt_state1"].to_numpy() == direct["gt_state1"].to_numpy()).all()
