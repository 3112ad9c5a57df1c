"""ROS 2 participant, without DDS traffic: name mapping, the live aligner against ingest, the sink's
message contents."""

from __future__ import annotations

import math

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from terrainml.io import cdr
from terrainml.io.ingest import load_run
from terrainml.io.topicmap import load_topic_map
from terrainml.robot import load_robot
from terrainml.sim.generate import simulate
from terrainml.sim.output import write_mcap
from terrainml.stream.transports.ros2.align import LiveAligner
from terrainml.stream.transports.ros2.names import (
    Ros2NameError, dds_topic_name, dds_type_name, parse_url, ros_topic_name, ros_type_name,
)
from terrainml.stream.transports.ros2.sink import _cov6, ros_time
from terrainml.stream.transports.ros2.types import Imu, JointState
from terrainml.stream.transports.sources import iter_table_samples


def test_names_follow_the_ros2_design_article():
    # "Topic and Service name mapping to DDS": rt/ prefix, pkg::msg::dds_::Type_
    assert dds_topic_name("/imu/data") == "rt/imu/data"
    assert dds_topic_name("joint_states") == "rt/joint_states"
    assert ros_topic_name("rt/imu/data") == "/imu/data"
    assert ros_topic_name("rq/add_two_intsRequest") is None
    assert dds_type_name("sensor_msgs/msg/JointState") == "sensor_msgs::msg::dds_::JointState_"
    assert dds_type_name("nav_msgs/Odometry") == "nav_msgs::msg::dds_::Odometry_"
    assert ros_type_name("std_msgs::msg::dds_::Float64_") == "std_msgs/msg/Float64"
    assert Imu.__idl_typename__ == "sensor_msgs::msg::dds_::Imu_"  # what the DDS topic type is called
    with pytest.raises(Ros2NameError):
        dds_topic_name("/a//b")
    with pytest.raises(Ros2NameError):
        dds_type_name("Imu")


def test_url_domain_and_options():
    assert parse_url("ros2://").domain_id == 0
    assert parse_url("ros2://7?qos=reliable", ("qos",)).options == {"qos": "reliable"}
    with pytest.raises(Ros2NameError, match="out of range"):
        parse_url("ros2://300")
    with pytest.raises(Ros2NameError, match="unknown option"):
        parse_url("ros2://1?speed=3", ("qos",))


def test_payload_is_xcdr1_little_endian_and_ingest_decodes_it():
    # the bytes cyclonedds puts on the wire decode with ingest's vectorised CDR decoder (the MCAP path)
    msg = JointState(name=["wheel1_drive", "wheel2_drive"], velocity=[1.5, -2.0])
    msg.header.stamp.sec, msg.header.stamp.nanosec = 12, 345
    raw = msg.serialize()
    assert raw[:4] == b"\x00\x01\x00\x00"
    parts, bad = cdr.decode_block("joint_state", "sensor_msgs/msg/JointState", [raw], np.array([0]))
    assert bad == 0 and parts[0]["t_ns"][0] == 12_000_000_345
    assert parts[0]["velocity"].tolist() == [[1.5, -2.0]]
    assert parts[0]["names"] == ("wheel1_drive", "wheel2_drive")


def test_ros_time_and_covariance_layout():
    t = ros_time(3_000_000_007)
    assert (t.sec, t.nanosec) == (3, 7)
    c = _cov6(np.array([[1.0, 0.1, 0.2], [0.1, 2.0, 0.3], [0.2, 0.3, 3.0]]))
    m = np.array(c).reshape(6, 6)
    assert m[0, 0] == 1.0 and m[1, 1] == 2.0 and m[5, 5] == 3.0 and m[0, 5] == 0.2 and m[5, 1] == 0.3


@pytest.fixture(scope="module")
def sand_log(tmp_path_factory):
    path = tmp_path_factory.mktemp("ros2") / "sand.mcap"
    write_mcap(simulate("dry_sand", "stop_and_go", duration_s=6.0, seed=31), path)
    return path


def _messages(path, tmap):
    """The log's mapped messages in log order, decoded by mcap_ros2 (not by terrainml's reader)."""
    by = tmap.by_topic()
    with open(path, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        return [(ch.topic, cdr.from_object(by[ch.topic].decode_kind, obj, m.log_time))
                for _, ch, m, obj in reader.iter_decoded_messages(topics=list(by), log_time_order=True)]


def _same(a: dict, b: dict) -> list[str]:
    out = []
    for k, v in a.items():
        if k == "run_id":
            continue
        w = b.get(k, "<missing>")
        if not (v == w or (isinstance(v, float) and isinstance(w, float) and math.isnan(v) and math.isnan(w))):
            out.append(k)
    return out


def test_live_aligner_gives_ingests_samples_message_by_message(sand_log):
    """One message at a time, in log order: the samples equal the ingested table's rows exactly."""
    tmap = load_topic_map(None)
    offline = [s.columns for s in iter_table_samples(load_run(sand_log).table)]
    al = LiveAligner(tmap, load_robot(), name="test", warmup_wait_s=0.0)
    live = []
    for topic, part in _messages(sand_log, tmap):
        al.add(topic, part)
        live += al.poll()
    live += al.finish()
    assert len(live) == len(offline) == 601
    diffs = {k for a, b in zip(offline, live) for k in _same(a, b)}
    assert not diffs
    assert al.t0_ns == min(int(p["t_ns"][0]) for _, p in _messages(sand_log, tmap))


def test_live_aligner_stale_topic_goes_invalid_and_late_message_is_counted(sand_log):
    tmap = load_topic_map(None)
    msgs = _messages(sand_log, tmap)
    t0 = min(int(p["t_ns"][0]) for _, p in msgs)
    al = LiveAligner(tmap, load_robot(), name="test", warmup_wait_s=0.0, reorder_s=0.05)
    out, held = [], None
    for topic, part in msgs:
        rel = (int(part["t_ns"][0]) - t0) * 1e-9
        if topic == "/wheels/joint_states" and rel > 3.0:
            continue                     # the wheel publisher stops at 3 s
        if topic == "/imu" and held is None and 2.0 < rel:
            held = (topic, part)         # one IMU message delivered 0.5 s late
            continue
        if held is not None and rel > 2.5 and held[0] != "done":
            al.add(*held)
            held = ("done", None)
        al.add(topic, part)
        out += al.poll()
    valid = {round(s["t_s"], 2): s["wheels_valid"] for s in out}
    assert all(valid[t] for t in valid if 0.5 < t < 2.99)
    # stale within the gap rule (0.02 s) plus reorder_s, long before the end of the stream
    assert not any(valid[t] for t in valid if t > 3.03)
    assert max(valid) > 5.0
    assert al.stats()["late"] == {"/imu": 1}


def test_live_aligner_clock_jump_starts_a_new_timeline(sand_log):
    tmap = load_topic_map(None)
    msgs = _messages(sand_log, tmap)
    t0 = min(int(p["t_ns"][0]) for _, p in msgs)
    al = LiveAligner(tmap, load_robot(), name="test", warmup_wait_s=0.0)
    out = []
    for topic, part in msgs:
        if (int(part["t_ns"][0]) - t0) * 1e-9 > 3.0:
            part = {**part, "t_ns": part["t_ns"] + 100_000_000_000}   # every clock steps +100 s at 3 s
        al.add(topic, part)
        out += al.poll()
    out += al.finish()
    t = np.array([s["t_s"] for s in out])
    assert np.all(np.diff(t[t < 50]) > 0) and np.all(np.diff(t[t > 50]) > 0)
    assert 2.9 < t[t < 50].max() <= 3.01 and 102.9 < t[t > 50].min() < 103.1
    assert al.stats()["timelines"] == 2


def test_a_backlogged_topic_is_not_a_clock_jump(sand_log):
    """One topic delivered 1.5 s behind the others (a stalled reader): late, never a new timeline."""
    tmap = load_topic_map(None)
    msgs = _messages(sand_log, tmap)
    al = LiveAligner(tmap, load_robot(), name="test", warmup_wait_s=0.0)
    out, queue = [], []
    for topic, part in msgs:
        if topic == "/wheels/joint_states" and (int(part["t_ns"][0]) - int(msgs[0][1]["t_ns"][0])) > 2e9:
            queue.append((topic, part))
            if len(queue) < 150:
                continue
            topic, part = queue.pop(0)
        al.add(topic, part)
        out += al.poll()
    for topic, part in queue:
        al.add(topic, part)
    out += al.finish()
    assert al.stats()["timelines"] == 1 and not al.stats()["off_timeline"]
    t = [s["t_s"] for s in out]
    assert t == sorted(t) and len(t) == 601
    assert al.stats()["late"]["/wheels/joint_states"] > 100


def test_float64_multiarray_decodes_alike_on_both_paths_and_maps_by_index(tmp_path):
    """The MCAP path (vectorised CDR) and the DDS path (from_object) give the same ``array`` part;
    an ``array`` map entry puts wheel i at index + i - 1 (a value the message lacks: NaN)."""
    from terrainml.io.ingest.signals import SourceFacts, signals_for
    from terrainml.io.topicmap import TopicMapError
    from terrainml.stream.transports.ros2.types import Float64MultiArray, MultiArrayDimension, MultiArrayLayout

    msgs = [Float64MultiArray(MultiArrayLayout([MultiArrayDimension("wheels", 3, 3)], 0), [1.0, -2.5, 3.0]),
            Float64MultiArray(data=[4.0, 5.0])]
    parts, bad = cdr.decode_block("array", "std_msgs/msg/Float64MultiArray", [m.serialize() for m in msgs],
                                  np.array([10, 20]))
    assert bad == 0
    for m, t in zip(msgs, (10, 20)):
        obj = cdr.from_object("array", m, t)
        (p,) = [p for p in parts if p["t_ns"][0] == t]
        assert np.array_equal(p["data"], obj["data"]) and np.array_equal(p["width"], obj["width"])
    f = tmp_path / "m.yaml"
    f.write_text("sources:\n  - topic: /w\n    type: std_msgs/msg/Float64MultiArray\n    kind: array\n"
                 "    columns: {\"wheel{i}_omega_radps\": {index: 0}}\n")
    tmap = load_topic_map(str(f))
    part = cdr.from_object("array", msgs[1], 0)
    sig = signals_for(tmap.sources[0], part, np.zeros(1), load_robot(), tmap, SourceFacts(gap_s=0.02))
    assert [(s.column, s.method) for s in sig] == [(f"wheel{i}_omega_radps", "previous") for i in (1, 2, 3)]
    assert [s.values[0] for s in sig][:2] == [4.0, 5.0] and np.isnan(sig[2].values[0])
    f.write_text("sources:\n  - {topic: /w, type: std_msgs/msg/Float64MultiArray, kind: array,"
                 " columns: {x: {index: -1}}}\n")
    with pytest.raises(TopicMapError, match="integer index"):
        load_topic_map(str(f))


def test_a_tick_is_served_with_the_message_that_completes_its_bracket(sand_log):
    """No wait beyond the data: after the warm-up, tick k comes out of the poll that follows the
    last message it needs (on every topic, the first one stamped after the tick), not later. (A
    topic published only on change, e.g. labels, is waited for ``reorder_s`` of the others' stamps
    instead: the serving inputs here are periodic.)"""
    tmap = load_topic_map(None)
    inputs = ["/imu", "/camera/odom/sample", "/wheels/joint_states", "/wheels/motor_current", "/cmd_vel"]
    msgs = [m for m in _messages(sand_log, tmap) if m[0] in inputs]
    al = LiveAligner(tmap, load_robot(), name="test", warmup_wait_s=0.0, required=inputs)
    served_at = {}
    for i, (topic, part) in enumerate(msgs):
        al.add(topic, part)
        for s in al.poll():
            served_at[round(s["t_s"] * 100)] = i
    t0 = al.t0_ns
    stamps: dict[str, list] = {}
    for i, (topic, part) in enumerate(msgs):
        if topic in al._prod.by_topic:
            stamps.setdefault(topic, []).append(((int(part["t_ns"][0]) - t0) * 1e-9, i))
    start = served_at[0]                       # the warm-up's ticks come out together
    checked = 0
    for k, i in served_at.items():
        need = max(next(j for t, j in v if t > k / 100 + 1e-9) for v in stamps.values()
                   if v[-1][0] > k / 100 + 1e-9)
        if need > start:
            assert i == need, k
            checked += 1
    assert checked > 500
