"""An independent ROS 2 peer for the interop tests: replays a log onto DDS, or records terrainml's output.

Run as its own process (``python ros2_peer.py publish|listen|write ...``). It never imports
terrainml: message types are defined here with cyclonedds' own IDL classes (the rmw_cyclonedds_cpp
names, ``pkg::msg::dds_::Type_``, topics ``rt/...``), an MCAP is read with the ``mcap`` /
``mcap_ros2`` libraries, a BorealTC run with the csv module, and the recorder writes what it
receives as JSON lines.

Two message sources, each with its own topic set (and writers):

* ``--mcap LOG``: the default topic map's inputs (:data:`INPUTS`, the reference robot) of a log;
* ``--borealtc CLASS_DIR:ID`` (e.g. ``.../borealtc/ASPHALT:04``): one BorealTC run (``pro_ID.csv``,
  ``imu_ID.csv``) as a Husky publishes it (:data:`HUSKY`, the ``husky_ros2`` map): ``/joint_states``
  (the four ``*_wheel_joint`` names, velocity = the side's speed / 0.1651 m in rad/s, left to
  front_left and rear_left; position and effort empty) and ``/imu/data`` (gyro and accelerometer as
  recorded, orientation identity with ``orientation_covariance[0] = -1``: REP 145's "no
  orientation"), header stamp = 1_700_000_000 s + the csv time, over the time both files cover.

publish: every message of the source's topics, in stamp order, at ``--speed`` x real time (source
timestamp = the log time), after every topic has a matched subscriber (or ``--match-timeout-s``).
Fault injections: ``--stop-topic T --stop-at-s S`` (T goes silent S s into the log),
``--pause-topic T|all --pause-at-s S --pause-s D`` (T's messages of [S, S + D) not sent),
``--restart-at-s S --restart-s D`` (the publisher leaves the domain at S and joins again as a new
participant D s later), ``--late-wrong-type-topic T --late-at-s S`` (a second publisher of T with
type std_msgs/Float64 appears at S), ``--nan-joint J1,J2 --nan-at-s S --nan-s D`` (those joints'
velocities NaN for D s: the source's JointState topic),
``--wrong-type-topic T`` (T published as std_msgs/Float64 instead), ``--jump-at-s S --jump-s J``
(every stamp after S s shifted by J s), ``--swap-every K`` (every K-th pair of IMU messages
published in reverse order), ``--burst-every K`` (K ticks held, then sent at once).
Every fault applies the same way to either source, the IMU swap to its IMU topic.
``--wheel-array T``: each JointState of ``/wheels/joint_states`` also published on T as a
std_msgs/Float64MultiArray of the ``wheel{i}_drive`` velocities (wheel order), source timestamp = its
header stamp (the array has no header).

listen: subscribes to the four terrainml topics, writes one JSON line per message to ``--out``
(with ``wall_s``, this machine's monotonic clock when it was taken), exits after ``--idle-s``
without a message (or ``--max-s``).

write: the source's messages without any fault (``--loop`` times, stamps continuing) to the MCAP
``--out`` (CDR, message definitions from rosbags' ROS 2 Humble type store, log time = the
stamp): the same run as a log file, for ``terrainml predict --source LOG``.
"""

import argparse
import csv
import gc
import heapq
import json
import sys
import time
from pathlib import Path
from dataclasses import dataclass, field

import cyclonedds.idl.types as t
from cyclonedds.core import Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration


@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: t.int32 = 0
    nanosec: t.uint32 = 0


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time = field(default_factory=Time)
    frame_id: str = ""


@dataclass
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: t.float64 = 0.0
    y: t.float64 = 0.0
    z: t.float64 = 0.0


@dataclass
class Point(IdlStruct, typename="geometry_msgs::msg::dds_::Point_"):
    x: t.float64 = 0.0
    y: t.float64 = 0.0
    z: t.float64 = 0.0


@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: t.float64 = 0.0
    y: t.float64 = 0.0
    z: t.float64 = 0.0
    w: t.float64 = 1.0


@dataclass
class Pose(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
    position: Point = field(default_factory=Point)
    orientation: Quaternion = field(default_factory=Quaternion)


@dataclass
class PoseWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::PoseWithCovariance_"):
    pose: Pose = field(default_factory=Pose)
    covariance: t.array[t.float64, 36] = field(default_factory=lambda: [0.0] * 36)


@dataclass
class Twist(IdlStruct, typename="geometry_msgs::msg::dds_::Twist_"):
    linear: Vector3 = field(default_factory=Vector3)
    angular: Vector3 = field(default_factory=Vector3)


@dataclass
class TwistWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::TwistWithCovariance_"):
    twist: Twist = field(default_factory=Twist)
    covariance: t.array[t.float64, 36] = field(default_factory=lambda: [0.0] * 36)


@dataclass
class Imu(IdlStruct, typename="sensor_msgs::msg::dds_::Imu_"):
    header: Header = field(default_factory=Header)
    orientation: Quaternion = field(default_factory=Quaternion)
    orientation_covariance: t.array[t.float64, 9] = field(default_factory=lambda: [0.0] * 9)
    angular_velocity: Vector3 = field(default_factory=Vector3)
    angular_velocity_covariance: t.array[t.float64, 9] = field(default_factory=lambda: [0.0] * 9)
    linear_acceleration: Vector3 = field(default_factory=Vector3)
    linear_acceleration_covariance: t.array[t.float64, 9] = field(default_factory=lambda: [0.0] * 9)


@dataclass
class JointState(IdlStruct, typename="sensor_msgs::msg::dds_::JointState_"):
    header: Header = field(default_factory=Header)
    name: t.sequence[str] = field(default_factory=list)
    position: t.sequence[t.float64] = field(default_factory=list)
    velocity: t.sequence[t.float64] = field(default_factory=list)
    effort: t.sequence[t.float64] = field(default_factory=list)


@dataclass
class Odometry(IdlStruct, typename="nav_msgs::msg::dds_::Odometry_"):
    header: Header = field(default_factory=Header)
    child_frame_id: str = ""
    pose: PoseWithCovariance = field(default_factory=PoseWithCovariance)
    twist: TwistWithCovariance = field(default_factory=TwistWithCovariance)


@dataclass
class Float64(IdlStruct, typename="std_msgs::msg::dds_::Float64_"):
    data: t.float64 = 0.0


@dataclass
class MultiArrayDimension(IdlStruct, typename="std_msgs::msg::dds_::MultiArrayDimension_"):
    label: str = ""
    size: t.uint32 = 0
    stride: t.uint32 = 0


@dataclass
class MultiArrayLayout(IdlStruct, typename="std_msgs::msg::dds_::MultiArrayLayout_"):
    dim: t.sequence[MultiArrayDimension] = field(default_factory=list)
    data_offset: t.uint32 = 0


@dataclass
class Float64MultiArray(IdlStruct, typename="std_msgs::msg::dds_::Float64MultiArray_"):
    layout: MultiArrayLayout = field(default_factory=MultiArrayLayout)
    data: t.sequence[t.float64] = field(default_factory=list)


@dataclass
class ObjectHypothesis(IdlStruct, typename="vision_msgs::msg::dds_::ObjectHypothesis_"):
    class_id: str = ""
    score: t.float64 = 0.0


@dataclass
class Classification(IdlStruct, typename="vision_msgs::msg::dds_::Classification_"):
    header: Header = field(default_factory=Header)
    results: t.sequence[ObjectHypothesis] = field(default_factory=list)


@dataclass
class KeyValue(IdlStruct, typename="diagnostic_msgs::msg::dds_::KeyValue_"):
    key: str = ""
    value: str = ""


@dataclass
class DiagnosticStatus(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticStatus_"):
    level: t.byte = 0
    name: str = ""
    message: str = ""
    hardware_id: str = ""
    values: t.sequence[KeyValue] = field(default_factory=list)


@dataclass
class DiagnosticArray(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticArray_"):
    header: Header = field(default_factory=Header)
    status: t.sequence[DiagnosticStatus] = field(default_factory=list)


# the default topic map's inputs (what the simulator's MCAP carries)
INPUTS = {"/imu": Imu, "/camera/odom/sample": Odometry, "/wheels/joint_states": JointState,
          "/wheels/motor_current": JointState, "/cmd_vel": Twist}
# a Husky's topics (the husky_ros2 map), what the BorealTC source publishes
HUSKY = {"/joint_states": JointState, "/imu/data": Imu}
OUTPUTS = {"/terrainml/desired_slip": Float64MultiArray, "/terrainml/terrain": Classification,
           "/diagnostics": DiagnosticArray, "/terrainml/odometry": Odometry}


def _qos(reliable: bool) -> Qos:
    if reliable:
        return Qos(Policy.Reliability.Reliable(duration(milliseconds=200)), Policy.History.KeepLast(1000))
    return Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(5))


def _header(h, shift_ns: int) -> Header:
    ns = h.stamp.sec * 1_000_000_000 + h.stamp.nanosec + shift_ns
    return Header(Time(ns // 1_000_000_000, ns % 1_000_000_000), h.frame_id)


def _vec(cls, v):
    return cls(v.x, v.y, v.z)


def _convert(cls, m, shift_ns: int):
    """A decoded message (mcap_ros2's, or this file's) -> this file's IDL object ``cls``, stamps shifted."""
    if cls is Imu:
        return Imu(_header(m.header, shift_ns), Quaternion(m.orientation.x, m.orientation.y, m.orientation.z,
                                                           m.orientation.w), list(m.orientation_covariance),
                   _vec(Vector3, m.angular_velocity), list(m.angular_velocity_covariance),
                   _vec(Vector3, m.linear_acceleration), list(m.linear_acceleration_covariance))
    if cls is Odometry:
        p, tw = m.pose.pose, m.twist.twist
        q = p.orientation
        return Odometry(_header(m.header, shift_ns), m.child_frame_id,
                        PoseWithCovariance(Pose(_vec(Point, p.position), Quaternion(q.x, q.y, q.z, q.w)),
                                           list(m.pose.covariance)),
                        TwistWithCovariance(Twist(_vec(Vector3, tw.linear), _vec(Vector3, tw.angular)),
                                            list(m.twist.covariance)))
    if cls is JointState:
        return JointState(_header(m.header, shift_ns), list(m.name), list(m.position), list(m.velocity),
                          list(m.effort))
    return Twist(_vec(Vector3, m.linear), _vec(Vector3, m.angular))


class McapSource:
    """The default topic map's inputs of an MCAP log, decoded by mcap_ros2 one at a time."""

    topics = INPUTS
    imu_topic = "/imu"
    joint_topic = "/wheels/joint_states"

    def __init__(self, path: str):
        from mcap.reader import make_reader

        self.path = path
        with open(path, "rb") as fh:
            stats = make_reader(fh).get_summary().statistics
        # one loop of the log; the next starts a period after its last message
        self.span_ns = stats.message_end_time - stats.message_start_time + 10_000_000

    def messages(self):
        """(topic, log time ns, message) in log time order (a long log starts at once)."""
        from mcap.reader import make_reader
        from mcap_ros2.decoder import DecoderFactory

        with open(self.path, "rb") as fh:
            reader = make_reader(fh, decoder_factories=[DecoderFactory()])
            for _, ch, rec, m in reader.iter_decoded_messages(topics=list(INPUTS), log_time_order=True):
                yield ch.topic, rec.log_time, m


#: header stamp of a BorealTC run's csv time 0
BOREAL_EPOCH_NS = 1_700_000_000 * 1_000_000_000
HUSKY_WHEEL_RADIUS_M = 0.1651
HUSKY_LEFT = ("front_left_wheel_joint", "rear_left_wheel_joint")
HUSKY_RIGHT = ("front_right_wheel_joint", "rear_right_wheel_joint")


def _csv_rows(path: Path) -> list[dict]:
    with open(path, newline="") as fh:
        return [{k: float(v) for k, v in row.items()} for row in csv.DictReader(fh)]


class BorealSource:
    """One BorealTC run (``CLASS_DIR:ID``) as a Husky's ``/joint_states`` and ``/imu/data``."""

    topics = HUSKY
    imu_topic = "/imu/data"
    joint_topic = "/joint_states"

    def __init__(self, run: str):
        folder, run_id = run.rsplit(":", 1)
        pro = _csv_rows(Path(folder) / f"pro_{run_id}.csv")
        imu = _csv_rows(Path(folder) / f"imu_{run_id}.csv")
        # the time both files cover (as the dataset spec's span: overlap)
        t0, t1 = max(pro[0]["time"], imu[0]["time"]), min(pro[-1]["time"], imu[-1]["time"])
        names = [HUSKY_LEFT[0], HUSKY_RIGHT[0], HUSKY_LEFT[1], HUSKY_RIGHT[1]]
        r = HUSKY_WHEEL_RADIUS_M
        joints = [(self._ns(p["time"]), 1, "/joint_states", JointState(
            self._header(p["time"], ""), list(names), [],
            [p["velL"] / r, p["velR"] / r, p["velL"] / r, p["velR"] / r], [])) for p in pro if t0 <= p["time"] <= t1]
        imus = [(self._ns(i["time"]), 0, "/imu/data", Imu(
            self._header(i["time"], "base_link"), Quaternion(0.0, 0.0, 0.0, 1.0), [-1.0] + [0.0] * 8,
            Vector3(i["wx"], i["wy"], i["wz"]), [0.0] * 9, Vector3(i["ax"], i["ay"], i["az"]), [0.0] * 9))
            for i in imu if t0 <= i["time"] <= t1]
        self._msgs = list(heapq.merge(imus, joints, key=lambda x: (x[0], x[1])))
        # one loop of the run, a whole number of 10-ms ticks (the stamps of its wheel service are
        # not on that grid): the next loop starts within 10 ms after its last message
        self.span_ns = (-(-(self._msgs[-1][0] - self._msgs[0][0]) // 10_000_000) + 1) * 10_000_000

    @staticmethod
    def _ns(t_s: float) -> int:
        return BOREAL_EPOCH_NS + round(t_s * 1e9)

    @classmethod
    def _header(cls, t_s: float, frame: str) -> Header:
        ns = cls._ns(t_s)
        return Header(Time(ns // 1_000_000_000, ns % 1_000_000_000), frame)

    def messages(self):
        for ns, _, topic, m in self._msgs:
            yield topic, ns, m


def _source(a):
    if bool(a.mcap) == bool(a.borealtc):
        raise SystemExit("peer: give one of --mcap LOG or --borealtc CLASS_DIR:ID")
    return McapSource(a.mcap) if a.mcap else BorealSource(a.borealtc)


class _Msg:
    """A decoded message with some fields replaced."""

    def __init__(self, m, **kw):
        self.__dict__.update({k: getattr(m, k) for k in ("header", "name", "position", "velocity", "effort")})
        self.__dict__.update(kw)


def _nan_joint(m, joints: str):
    """The JointState with NaN velocities on the joints ``joints`` (comma-separated)."""
    bad = set(joints.split(","))
    return _Msg(m, velocity=[float("nan") if n in bad else v for n, v in zip(m.name, m.velocity)])


def _faults(a) -> list[dict]:
    """The fault plan: ``--faults FILE`` (JSON list of {kind: pause|nan|restart, at_s, dur_s, topic|joint},
    log seconds from the start of the first loop) and the single-fault options."""
    faults = json.load(open(a.faults)) if a.faults else []
    if a.pause_topic:
        faults.append({"kind": "pause", "topic": a.pause_topic, "at_s": a.pause_at_s, "dur_s": a.pause_s})
    if a.restart_at_s is not None:
        faults.append({"kind": "restart", "at_s": a.restart_at_s, "dur_s": a.restart_s})
    if a.nan_joint:
        for j in a.nan_joint.split(","):
            faults.append({"kind": "nan", "joint": j, "at_s": a.nan_at_s, "dur_s": a.nan_s})
    return faults


def _stamp_ns(h) -> int:
    return h.stamp.sec * 1_000_000_000 + h.stamp.nanosec


def _wheel_array(js: JointState) -> Float64MultiArray:
    """The drive joints' velocities, wheel 1..N, as a Float64MultiArray."""
    by = dict(zip(js.name, js.velocity))
    wheels = sorted((int(n[5:-6]), by[n]) for n in js.name if n.startswith("wheel") and n.endswith("_drive"))
    return Float64MultiArray(MultiArrayLayout([MultiArrayDimension("wheels", len(wheels), len(wheels))], 0),
                             [v for _, v in wheels])


def _wait_matched(writers: dict, timeout_s: float) -> None:
    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end:
        if all(w.get_matched_subscriptions() for w in writers.values()):
            return
        time.sleep(0.05)
    print("peer: not every topic has a subscriber; publishing anyway", file=sys.stderr, flush=True)


def publish(a) -> None:
    src = _source(a)
    dp = DomainParticipant(a.domain)
    types = dict(src.topics)
    if a.wrong_type_topic:
        types[a.wrong_type_topic] = Float64
    if a.wheel_array:
        types[a.wheel_array] = Float64MultiArray
    writers = {tp: DataWriter(dp, Topic(dp, "rt" + tp, cls), qos=_qos(a.reliable)) for tp, cls in types.items()}
    print("peer: writers up", file=sys.stderr, flush=True)
    _wait_matched(writers, a.match_timeout_s)
    time.sleep(a.settle_s)
    held: list = []
    imu_prev = None
    n = 0
    span_ns = src.span_ns
    log_messages = src.messages
    t0_log = next(log_messages())[1]
    faults = _faults(a)
    late_writer = None
    restarted: set[int] = set()
    print("peer: publishing", file=sys.stderr, flush=True)
    t0_wall = time.monotonic()
    for loop, (topic, log_time, ros_msg) in ((k, m) for k in range(a.loop) for m in log_messages()):
        log_time += loop * span_ns
        rel_s = (log_time - t0_log) * 1e-9
        if a.stop_topic == topic and rel_s >= a.stop_at_s:
            continue
        active = [f for f in faults if f["at_s"] <= rel_s < f["at_s"] + f["dur_s"]]
        if any(f["kind"] == "pause" and f["topic"] in (topic, "all") for f in active):
            continue
        restart = next((k for k, f in enumerate(faults) if f["kind"] == "restart" and k not in restarted
                        and f["at_s"] <= rel_s), None)
        if restart is not None:
            # the publisher restarts as a new participant (a driver restart): writers gone, back after a while
            restarted.add(restart)
            held, late_writer = [], None
            writers.clear()
            writers, dp = {}, None
            gc.collect()                      # the old participant leaves the domain
            time.sleep(faults[restart]["dur_s"] / a.speed if a.speed > 0 else 0.0)
            dp = DomainParticipant(a.domain)
            writers = {tp: DataWriter(dp, Topic(dp, "rt" + tp, cls), qos=_qos(a.reliable)) for tp, cls in types.items()}
            _wait_matched(writers, 10.0)
            print("peer: restarted", file=sys.stderr, flush=True)
        if any(f["kind"] == "restart" for f in active):
            continue                          # what the driver would have sent while it was down
        if a.late_wrong_type_topic and late_writer is None and rel_s >= a.late_at_s:
            late_dp = DomainParticipant(a.domain)    # a second node: one participant holds one type per topic
            late_writer = DataWriter(late_dp, Topic(late_dp, "rt" + a.late_wrong_type_topic, Float64),
                                     qos=_qos(a.reliable))
            late_writer.write(Float64(1.0))
            print("peer: wrong type up", file=sys.stderr, flush=True)
        nan = [f["joint"] for f in active if f["kind"] == "nan"]
        if nan and topic == src.joint_topic:
            ros_msg = _nan_joint(ros_msg, ",".join(nan))
        shift = int(a.jump_s * 1e9) if a.jump_at_s is not None and rel_s >= a.jump_at_s else 0
        shift += loop * span_ns
        if a.wrong_type_topic == topic:
            msg = Float64(1.0)
        else:
            msg = _convert(src.topics[topic], ros_msg, shift)
        item = (writers[topic], msg, log_time - loop * span_ns + shift)
        if a.swap_every and topic == src.imu_topic:
            n_imu = getattr(publish, "_n_imu", 0) + 1
            publish._n_imu = n_imu
            if imu_prev is None and n_imu % a.swap_every == 0:
                imu_prev = item
                continue
            if imu_prev is not None:
                held += [item, imu_prev]
                imu_prev = None
                item = None
        if item is not None:
            held.append(item)
        if a.wheel_array and topic == "/wheels/joint_states":
            held.append((writers[a.wheel_array], _wheel_array(msg), _stamp_ns(msg.header)))
        burst = a.burst_every and (n % (a.burst_every * 6) != 0)
        if burst:
            n += 1
            continue
        if a.speed > 0:
            delay = rel_s / a.speed - (time.monotonic() - t0_wall)
            if delay > 0:
                time.sleep(delay)
        for w, m, ts in held:
            w.write(m, timestamp=ts)
        held = []
        n += 1
    for w, m, ts in held:
        w.write(m, timestamp=ts)
    time.sleep(a.linger_s)
    print(f"peer: published {n} messages", file=sys.stderr, flush=True)


def write(a) -> None:
    """The source's messages, no fault, ``--loop`` times (stamps continuing), to the MCAP ``--out``."""
    from mcap_ros2.writer import Writer
    from rosbags.typesys import Stores, get_typestore

    src = _source(a)
    store = get_typestore(Stores.ROS2_HUMBLE)
    ros_type = {cls: cls.__idl_typename__.replace("::dds_::", "::").replace("::", "/").rstrip("_")
                for cls in set(src.topics.values())}
    with open(a.out, "wb") as fh:
        w = Writer(fh)
        schemas = {cls: w.register_msgdef(name, store.generate_msgdef(name, ros_version=2)[0])
                   for cls, name in ros_type.items()}
        n = 0
        for loop in range(a.loop):
            for topic, log_time, m in src.messages():
                shift = loop * src.span_ns
                cls = src.topics[topic]
                w.write_message(topic, schemas[cls], _convert(cls, m, shift), log_time + shift, log_time + shift)
                n += 1
        w.finish()
    print(f"peer: wrote {n} messages", file=sys.stderr, flush=True)


def _out_row(topic: str, m) -> dict:
    if topic == "/terrainml/desired_slip":
        return {"data": list(m.data), "dims": [(d.label, d.size, d.stride) for d in m.layout.dim]}
    if topic == "/terrainml/terrain":
        return {"stamp_ns": m.header.stamp.sec * 10**9 + m.header.stamp.nanosec,
                "results": [(r.class_id, r.score) for r in m.results]}
    if topic == "/diagnostics":
        st = m.status[0]
        return {"stamp_ns": m.header.stamp.sec * 10**9 + m.header.stamp.nanosec, "level": st.level,
                "name": st.name, "message": st.message, "values": {kv.key: kv.value for kv in st.values},
                "wall_s": time.monotonic(),
                "all": [{"level": s.level, "name": s.name, "message": s.message} for s in m.status]}
    tw = m.twist.twist
    return {"stamp_ns": m.header.stamp.sec * 10**9 + m.header.stamp.nanosec, "frame": m.header.frame_id,
            "child": m.child_frame_id, "vx": tw.linear.x, "vy": tw.linear.y, "wz": tw.angular.z,
            "cov": list(m.twist.covariance)}


def listen(a) -> None:
    dp = DomainParticipant(a.domain)
    readers = {tp: DataReader(dp, Topic(dp, "rt" + tp, cls), qos=_qos(True)) for tp, cls in OUTPUTS.items()}
    t_start = last = time.monotonic()
    got = False
    with open(a.out, "w") as fh:
        print("listener: up", file=sys.stderr, flush=True)
        while True:
            n = 0
            for tp, r in readers.items():
                for m in r.take(500):
                    if not getattr(getattr(m, "sample_info", None), "valid_data", True):
                        continue   # a writer going away (dispose / unregister)
                    fh.write(json.dumps({"topic": tp, "wall_s": time.monotonic(), **_out_row(tp, m)}) + "\n")
                    n += 1
            now = time.monotonic()
            if n:
                last, got = now, True
                fh.flush()
            if (got and now - last > a.idle_s) or now - t_start > a.max_s:
                break
            time.sleep(0.005)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("mode", choices=["publish", "listen", "write"])
    ap.add_argument("--domain", type=int, help="DDS domain id (publish, listen)")
    ap.add_argument("--mcap")
    ap.add_argument("--borealtc", help="CLASS_DIR:ID, a BorealTC run (pro_ID.csv, imu_ID.csv) on Husky topics")
    ap.add_argument("--out")
    ap.add_argument("--reliable", action="store_true")
    ap.add_argument("--speed", type=float, default=1.0)
    ap.add_argument("--match-timeout-s", type=float, default=60.0)
    ap.add_argument("--settle-s", type=float, default=0.5)
    ap.add_argument("--linger-s", type=float, default=1.0)
    ap.add_argument("--stop-topic")
    ap.add_argument("--stop-at-s", type=float, default=0.0)
    ap.add_argument("--wrong-type-topic")
    ap.add_argument("--jump-at-s", type=float)
    ap.add_argument("--jump-s", type=float, default=0.0)
    ap.add_argument("--swap-every", type=int, default=0)
    ap.add_argument("--burst-every", type=int, default=0)
    ap.add_argument("--wheel-array")
    ap.add_argument("--pause-topic", help="a topic, or all: its messages from --pause-at-s for --pause-s are not sent")
    ap.add_argument("--pause-at-s", type=float, default=0.0)
    ap.add_argument("--pause-s", type=float, default=0.0)
    ap.add_argument("--restart-at-s", type=float)
    ap.add_argument("--restart-s", type=float, default=1.0)
    ap.add_argument("--late-wrong-type-topic")
    ap.add_argument("--late-at-s", type=float, default=0.0)
    ap.add_argument("--nan-joint", help="joint names (comma-separated) whose velocity is NaN for a while")
    ap.add_argument("--nan-at-s", type=float, default=0.0)
    ap.add_argument("--nan-s", type=float, default=0.0)
    ap.add_argument("--faults", help="JSON file: a list of faults (see _faults)")
    ap.add_argument("--loop", type=int, default=1, help="replay the log this many times, stamps continuing")
    ap.add_argument("--idle-s", type=float, default=5.0)
    ap.add_argument("--max-s", type=float, default=300.0)
    a = ap.parse_args()
    if a.mode != "write" and a.domain is None:
        ap.error("--domain is required to publish or listen")
    {"publish": publish, "listen": listen, "write": write}[a.mode](a)


if __name__ == "__main__":
    main()
