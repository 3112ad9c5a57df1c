"""Live faults without DDS traffic: a paused topic rejoins the aligner's timeline, per-topic
freshness and loop lag on a hand-driven clock, what ``/diagnostics`` says (fast tier)."""

from __future__ import annotations

import logging
import math

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from terrainml.io import cdr
from terrainml.io.topicmap import load_topic_map
from terrainml.robot import load_robot
from terrainml.sim.generate import simulate
from terrainml.sim.output import write_mcap
from terrainml.stream.tick.inputs import MIN_TIMEOUT_S, InputWatch
from terrainml.stream.tick.message import DesiredSlip
from terrainml.stream.transports.ros2.align import LiveAligner


@pytest.fixture(scope="module")
def sand_msgs(tmp_path_factory):
    """A 12-s simulated run's mapped messages in log order, decoded by mcap_ros2."""
    path = tmp_path_factory.mktemp("faults") / "sand.mcap"
    write_mcap(simulate("dry_sand", "straight", duration_s=12.0, seed=33), path)
    tmap = load_topic_map(None)
    by = tmap.by_topic()
    with open(path, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        return [(ch.topic, cdr.from_object(by[ch.topic].decode_kind, obj, m.log_time))
                for _, ch, m, obj in reader.iter_decoded_messages(topics=list(by), log_time_order=True)]


def _feed(al, msgs, skip):
    t0 = min(int(p["t_ns"][0]) for _, p in msgs)
    out = []
    for topic, part in msgs:
        if skip(topic, (int(part["t_ns"][0]) - t0) * 1e-9):
            continue
        al.add(topic, part)
        out += al.poll()
    return out + al.finish()


@pytest.mark.parametrize("topic,group", [("/imu", "imu"), ("/wheels/joint_states", "wheels")])
def test_a_topic_paused_longer_than_the_clock_gap_rejoins_the_timeline(sand_msgs, topic, group, caplog):
    """The topic stops at 3 s and publishes again at 8 s (5 s > G = 1 s): its group is invalid in
    between and valid again from the return on, on one timeline, and the log says it returned."""
    al = LiveAligner(load_topic_map(None), load_robot(), name="test", warmup_wait_s=0.0)
    with caplog.at_level(logging.WARNING, logger="terrainml.stream"):
        out = _feed(al, sand_msgs, lambda tp, rel: tp == topic and 3.0 < rel < 8.0)
    valid = {round(s["t_s"], 2): s[f"{group}_valid"] for s in out}
    assert al.stats()["timelines"] == 1 and not al.stats()["off_timeline"]
    assert not any(v for t, v in valid.items() if 3.1 < t < 7.95)
    back = [v for t, v in valid.items() if 8.1 < t < 11.9]
    assert back and all(back)
    assert f"topic {topic} publishes again after 5.0 s" in caplog.text


def test_a_flush_decides_the_ticks_up_to_the_latest_stamp_and_the_grid_goes_on(sand_msgs):
    """Every topic silent (the source flushes after 1.5 s of wall time): the ticks up to the latest
    stamp come out at once instead of waiting for the return; when the messages come back on the
    timeline the grid goes on, every tick once, in order."""
    al = LiveAligner(load_topic_map(None), load_robot(), name="t", warmup_wait_s=0.0)
    t0 = min(int(p["t_ns"][0]) for _, p in sand_msgs)
    before = [(tp, p) for tp, p in sand_msgs if (int(p["t_ns"][0]) - t0) * 1e-9 <= 5.0]
    out = []
    for topic, part in before:
        al.add(topic, part)
        out += al.poll()
    latest = max(int(p["t_ns"][0]) for _, p in before)
    waiting = (latest - al.t0_ns) * 1e-9 - out[-1]["t_s"]
    assert waiting > 0.005                               # the last ticks wait for their next messages
    flushed = al.flush()
    assert flushed and abs(flushed[-1]["t_s"] - (latest - al.t0_ns) * 1e-9) < 0.0101
    assert al.flush() == []                              # nothing left to decide
    out += flushed
    for topic, part in sand_msgs[len(before):]:          # the topics return (a stalled publisher's backlog)
        al.add(topic, part)
        out += al.poll()
    out += al.finish()
    steps = np.diff([m["t_s"] for m in out])
    assert np.allclose(steps, 0.01) and al.stats()["timelines"] == 1
    assert out[-1]["t_s"] > 11.9


def test_the_clock_options_reach_the_aligner(sand_msgs):
    """With G = 30 s a 5-s step of every clock is no jump (one timeline); with G = 1 s it is."""
    def shifted(al):
        t0 = min(int(p["t_ns"][0]) for _, p in sand_msgs)
        for topic, part in sand_msgs:
            if (int(part["t_ns"][0]) - t0) * 1e-9 > 3.0:
                part = {**part, "t_ns": part["t_ns"] + 5_000_000_000}
            al.add(topic, part)
            al.poll()
        al.finish()
        return al.stats()["timelines"]

    robot, tmap = load_robot(), load_topic_map(None)
    assert shifted(LiveAligner(tmap, robot, name="t", warmup_wait_s=0.0, max_gap_s=30.0)) == 1
    assert shifted(LiveAligner(tmap, robot, name="t", warmup_wait_s=0.0, max_gap_s=1.0)) == 2


def test_the_aligner_knows_the_sensor_groups_its_map_feeds(sand_msgs):
    al = LiveAligner(load_topic_map("husky_ros2"), load_robot("husky"), name="t", warmup_wait_s=0.0)
    al.watch = InputWatch()
    t0 = int(sand_msgs[0][1]["t_ns"][0])
    # a Husky-shaped stream: four wheel joints and an IMU
    for k in range(80):
        t = np.array([t0 + k * 10_000_000], np.int64)
        names = ("front_left_wheel_joint", "front_right_wheel_joint", "rear_left_wheel_joint",
                 "rear_right_wheel_joint")
        al.add("/joint_states", {"t_ns": t, "names": names, "position": np.zeros((1, 4)),
                                 "velocity": np.ones((1, 4)), "effort": np.full((1, 4), np.nan)})
        al.add("/imu/data", {"t_ns": t, "orientation": np.array([[0.0, 0, 0, 1]]), "gyro": np.zeros((1, 3)),
                             "accel": np.array([[0.0, 0, 9.81]])})
        al.poll()
    assert al.mapped_groups is not None and al.watch.mapped_groups == al.mapped_groups
    assert "wheels" in al.mapped_groups and "imu" in al.mapped_groups
    assert "current" not in al.mapped_groups and "cam" not in al.mapped_groups


class Clock:
    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t


def _publish(w, clock, topic, seconds, hz=100.0, step=None):
    n = int(round(seconds * hz))
    for _ in range(n):
        clock.t += 1.0 / hz
        w.loop(1.0 / hz)
        w.on_message(topic)


def test_a_topic_is_silent_after_its_own_timeout_and_fresh_again_on_its_first_message(caplog):
    clock = Clock()
    w = InputWatch(clock)
    w.add_topic("/imu", "sensor_msgs/msg/Imu")
    w.add_topic("/slow", "sensor_msgs/msg/JointState")
    for _ in range(300):                       # /imu at 100 Hz, /slow at 2 Hz, for 3 s
        clock.t += 0.01
        w.loop(0.01)
        w.on_message("/imu")
        if round(clock.t * 100) % 50 == 0:
            w.on_message("/slow")
    assert w.topics["/imu"].timeout_s() == MIN_TIMEOUT_S
    assert w.topics["/slow"].timeout_s() == pytest.approx(2.5, rel=0.1)   # 5 periods of its own rate
    with caplog.at_level(logging.WARNING, logger="terrainml.stream"):
        for _ in range(10):                    # 1 s: /imu pauses, /slow goes on
            clock.t += 0.1
            w.loop(0.1)
            if round(clock.t * 10) % 5 == 0:
                w.on_message("/slow")
            w.update()
        silent = dict(w.update())
        assert list(silent) == ["/imu"] and silent["/imu"] == pytest.approx(1.0, abs=0.02)
        st = {s["name"]: s for s in w.statuses()}
        imu = st["terrainml: input /imu"]
        assert imu["level"] == 1 and "silent for 1.0 s" in imu["message"]
        assert st["terrainml: input /slow"]["level"] == 0
        clock.t += 0.01
        w.on_message("/imu")
        assert w.update() == []
    assert "topic /imu silent: no message for 0.6 s (timeout 0.50 s at 100 Hz)" in caplog.text
    assert "topic /imu fresh again after 1.0 s" in caplog.text


def test_no_silence_while_the_process_did_not_run():
    """The loop stalls for 2 s (CPU hogs): when it runs again, no topic is silent, every topic
    is waited for (grace), and the lag is counted. Every topic late together for less than 1 s
    (a stall of delivery) is no topic's silence either."""
    clock = Clock()
    w = InputWatch(clock)
    w.add_topic("/imu", "sensor_msgs/msg/Imu")
    w.add_topic("/wheels", "sensor_msgs/msg/JointState")
    for _ in range(200):
        clock.t += 0.01
        w.loop(0.01)
        w.on_message("/imu")
        w.on_message("/wheels")
    clock.t += 2.0                              # the process did not run for 2 s
    assert w.loop(0.1) == pytest.approx(1.9)
    assert w.update() == [] and w.in_grace()
    assert w.lags == 1 and w.max_lag_s == pytest.approx(1.9)
    for _ in range(40):                         # ran again: /wheels comes, /imu does not
        clock.t += 0.01
        w.loop(0.01)
        w.on_message("/wheels")
        if _ == 39:
            assert w.update() == []             # 0.4 s after the process ran again: not yet
    for _ in range(20):
        clock.t += 0.01
        w.loop(0.01)
        w.on_message("/wheels")
    assert [t for t, _ in w.update()] == ["/imu"]   # 0.6 s: silent
    for _ in range(50):                         # both publish again
        clock.t += 0.01
        w.loop(0.01)
        w.on_message("/imu")
        w.on_message("/wheels")
    assert w.update() == []
    for _ in range(70):                         # every topic late together for 0.7 s: no one's silence
        clock.t += 0.01
        w.loop(0.01)
    assert w.update() == []
    for _ in range(40):                         # 1.1 s: total silence, every topic said
        clock.t += 0.01
        w.loop(0.01)
    assert sorted(t for t, _ in w.update()) == ["/imu", "/wheels"]


def test_a_delivery_stall_caught_between_two_topics_is_no_topics_silence():
    """Delivery stalls for 0.7 s right after /wheels and /current but before /imu of one tick
    (a starved publisher writes its topics in turn): /imu is then 10 ms older than the others
    when every topic is late. Each topic's age is counted from the least overdue topic, so none is
    singled out; a real pause of /imu alone is still said at its 0.5 s timeout."""
    clock = Clock()
    w = InputWatch(clock)
    for topic in ("/imu", "/wheels", "/current"):
        w.add_topic(topic, "sensor_msgs/msg/JointState")
    for k in range(200):
        clock.t += 0.01
        w.loop(0.01)
        if k < 199:
            w.on_message("/imu")          # the stall comes before /imu's message of the last tick
        w.on_message("/wheels")
        w.on_message("/current")
    for _ in range(70):                   # 0.7 s with no message of any topic
        clock.t += 0.01
        w.loop(0.01)
        assert w.update() == []
    for _ in range(100):                  # all back; then /imu alone pauses
        clock.t += 0.01
        w.loop(0.01)
        for topic in ("/imu", "/wheels", "/current"):
            w.on_message(topic)
    said = []
    for k in range(60):
        clock.t += 0.01
        w.loop(0.01)
        w.on_message("/wheels")
        w.on_message("/current")
        said += [(k, t) for t, _ in w.update()]
    assert said and said[0][1] == "/imu" and 49 <= said[0][0] <= 51   # after its own 0.5 s


def test_invalid_values_are_counted_per_topic_and_field_and_are_not_silence():
    clock = Clock()
    w = InputWatch(clock)
    w.add_topic("/joint_states", "sensor_msgs/msg/JointState")
    names = ("left", "right")
    for k in range(100):
        clock.t += 0.01
        vel = np.array([[math.nan if k >= 50 else 1.0, 1.0]])
        w.on_message("/joint_states", {"t_ns": np.array([k]), "names": names, "velocity": vel,
                                       "position": np.zeros((1, 2)), "effort": np.full((1, 2), np.nan)},
                     empty=frozenset({"effort"}))     # an empty effort field is no invalid value
    assert w.topics["/joint_states"].invalid == {"velocity[left]": 50}
    assert w.update() == []
    (st,) = w.statuses()
    assert st["level"] == 0 and st["values"]["invalid_values"] == "50"
    assert st["values"]["invalid_velocity[left]"] == "50"


def _msg(t_s, reason="", ok=True, sensors=("wheels", "imu")):
    return DesiredSlip(t_s=t_s, seq=0, slip_desired=[0.1] * 4, slip_measured=[0.0] * 4, wheel_state=["steady"] * 4,
                       terrain_class=-1 if reason else 1, terrain_name="none" if reason else "ASPHALT",
                       confidence=0.0 if reason else 0.9, class_probabilities=[0.0] * 3, classification_age_s=0.1,
                       fallback=bool(reason), fallback_reason=reason, estimator_ok=ok, sensors=list(sensors))


def test_diagnostics_say_error_no_input_on_total_silence_and_name_each_silent_topic():
    from terrainml.stream.transports.ros2.sink import ERROR, OK, DiagnosticsState

    clock = Clock()
    w = InputWatch(clock)
    w.add_topic("/joint_states", "sensor_msgs/msg/JointState")
    w.add_topic("/imu/data", "sensor_msgs/msg/Imu")
    w.mapped_groups = ["wheels", "imu"]
    robot = load_robot("husky")
    d = DiagnosticsState(robot, ["wheels", "currents", "imu"], w)
    sample = {"wheels_valid": True, "imu_valid": True, "steer_valid": True, "current_valid": False}
    for k in range(100):
        clock.t += 0.01
        w.loop(0.01)
        w.on_message("/joint_states")
        w.on_message("/imu/data")
        d.tick(_msg(k * 0.01), sample, 1_000_000_000 + k * 10_000_000)
    _, (serving, *inputs) = d.statuses()
    assert serving["level"] == OK and serving["message"] == "serving ASPHALT"
    # one sensors_used, the message's; no steering group on a skid-steer robot; no unmapped group
    assert serving["values"]["sensors_used"] == "wheels,imu"
    assert serving["values"]["sensors_valid"] == "wheels,imu"
    assert not any(k.startswith(("rate_steer", "rate_current")) for k in serving["values"])
    assert all(s["level"] == OK for s in inputs)
    for _ in range(15):                       # every topic stops: the timer goes on, 1.5 s
        clock.t += 0.1
        w.loop(0.1)
    stamp, (serving, *inputs) = d.statuses()
    assert serving["level"] == ERROR and serving["message"].startswith("no input for 1.5 s")
    assert "/imu/data (1.5 s)" in serving["message"]
    assert [s["level"] for s in inputs] == [1, 1] and "/joint_states silent for 1.5 s" in inputs[0]["message"]
    assert stamp == 1_000_000_000 + 99 * 10_000_000 + 1_500_000_000    # the ROS time moved on with the wall


def test_neither_a_total_silence_nor_the_warm_up_after_it_says_ok():
    """Every topic stops; 1.5 s later the aligner's flush decides the last ticks, and that work
    delays the loop by 0.3 s. The silence began before the lag, so the lag hides no message: the
    serving status stays ERROR "no input" from 1 s on, through the lag and after it. When input
    comes back, the status says WARN "no tick" until the new timeline's first tick, never the last
    tick's OK. A lag that begins while input flows still restarts the count (a busy process's
    input is never silent)."""
    from terrainml.stream.transports.ros2.sink import ERROR, OK, WARN, DiagnosticsState

    clock = Clock()
    w = InputWatch(clock)
    for topic in ("/joint_states", "/imu/data"):
        w.add_topic(topic, "sensor_msgs/msg/Imu")
    d = DiagnosticsState(load_robot("husky"), ["wheels", "imu"], w)
    sample = {"wheels_valid": True, "imu_valid": True}

    def flow(seconds):
        for _ in range(int(round(seconds / 0.01))):
            clock.t += 0.01
            w.loop(0.01)
            w.on_message("/joint_states")
            w.on_message("/imu/data")
            d.tick(_msg(clock.t), sample, int(clock.t * 1e9))

    def level():
        return d.statuses()[1][0]["level"]

    flow(1.0)
    clock.t += 0.5                        # the process stalls while input flows: a lag
    w.loop(0.1)
    assert w.idle_s() == 0.0 and level() == OK
    flow(1.0)
    stopped, levels = clock.t, []
    for k in range(40):                   # 4 s without input; the flush's work at 1.5 s lags 0.3 s
        clock.t += 0.4 if k == 15 else 0.1
        assert w.loop(0.1) == pytest.approx(0.3 if k == 15 else 0.0)
        levels.append((clock.t - stopped, level()))
    assert w.lags == 2
    assert all(lv == ERROR for t, lv in levels if t > 1.0 + 1e-9), levels
    assert w.idle_s() == pytest.approx(clock.t - stopped)
    for _ in range(50):                   # input is back; the new timeline warms up without a tick
        clock.t += 0.01
        w.loop(0.01)
        w.on_message("/joint_states")
        w.on_message("/imu/data")
    serving = d.statuses()[1][0]
    assert serving["level"] == WARN and serving["message"].startswith("no tick for 4.8 s while input arrives")
    d.tick(_msg(clock.t), sample, int(clock.t * 1e9))
    assert level() == OK


def _predictor(robot, members=()):
    from stream_fakes import FakeClassifier, FakeEstimator, FakeTable

    from terrainml.features.windows import WindowSpec
    from terrainml.stream.tick.classify import ServingMember
    from terrainml.stream.tick.config import ServingConfig
    from terrainml.stream.tick.predictor import Predictor

    mem = [ServingMember(name, FakeClassifier(), WindowSpec(), sensors) for name, sensors in members]
    return Predictor(robot, FakeTable(), FakeClassifier(), FakeEstimator(robot), sensors=["wheels", "currents", "imu"],
                     config=ServingConfig(), members=mem)


def test_an_unmapped_group_is_said_once_and_serving_starts_on_the_member_without_it(caplog):
    from stream_fakes import make_samples

    robot = load_robot()
    pred = _predictor(robot, members=[("no_currents", ["wheels", "imu"])])
    samples = make_samples(robot, 3.0)
    for s in samples:                      # a map without currents: the columns never carry a value
        for i in range(1, robot.n_wheels + 1):
            s[f"wheel{i}_current_a"] = math.nan
    with caplog.at_level(logging.WARNING, logger="terrainml.stream"):
        pred.set_mapped_groups(["wheels", "steer", "imu", "cam"])
        out = [pred.step(s) for s in samples]
    assert "sensor group 'current' not mapped" in caplog.text
    assert "silent" not in caplog.text and not pred.counters.silent_episodes
    assert all(m.estimator_ok for m in out) and all(m.sensors == ["wheels", "imu"] for m in out)
    assert not out[0].slip_measured_note and out[0].to_dict()["slip_measured"] is not None


def test_slip_without_a_body_velocity_reference_is_absent_with_a_reason():
    from stream_fakes import make_samples

    robot = load_robot()
    pred = _predictor(robot, members=[("no_currents", ["wheels", "imu"])])
    pred.set_mapped_groups(["wheels", "steer", "imu"])
    msg = pred.step(make_samples(robot, 0.01)[0])
    d = msg.to_dict()
    assert d["slip_measured"] is None and "not observable" in d["slip_measured_note"]
    from terrainml.stream.transports.sinks import decode_can_frames, encode_can_frames

    assert all(math.isnan(v) for v in decode_can_frames(encode_can_frames(msg))["slip_measured"])
    assert DesiredSlip.from_json(msg.to_json()).slip_measured_note == d["slip_measured_note"]


class _Fused:
    def __init__(self):
        self.posterior = np.array([0.9, 0.1])
        self.stale = False

    def best(self):
        k = int(np.argmax(self.posterior))
        return k, float(self.posterior[k])


def test_no_flapping_after_a_recovery():
    """Staleness flickering every 0.25 s after a pause: the class turns stale at most once a
    second (a fresh class is served at once); an unhealthy estimator applies on its own tick."""
    from stream_fakes import FakeTable

    from terrainml.stream.tick.policy import ServingPolicy

    pol = ServingPolicy(FakeTable(), [0, 1], ["A", "B"])
    fused = _Fused()
    served = []
    for k in range(400):                              # 4 s at 100 Hz
        t = k / 100
        fused.stale = (k // 25) % 2 == 1              # the distance rule flickers every 0.25 s
        unhealthy = 100 <= k < 120                    # a sensor pause: estimator unhealthy
        dec = pol.decide(fused, estimator_ok=not unhealthy, classifier_error=False, age_s=0.1,
                         states=["steady"] * 2, v_long=[1.0, 1.0], t_s=t)
        served.append((t, dec.reason or dec.class_name))
    changes = [served[i][0] for i in range(1, len(served)) if served[i][1] != served[i - 1][1]]
    assert [r for t, r in served if 1.0 <= t < 1.2] == ["estimator_unhealthy"] * 20
    assert 1.0 in changes and 1.2 in changes          # the pause, and the recovery, at once
    stale_in = [served[i][0] for i in range(1, len(served))
                if served[i][1] == "stale_classification" != served[i - 1][1] and served[i][0] > 1.2]
    # the class turns stale at most once a second (not every 0.25 s), each time after a second served
    assert stale_in and all(b - a >= 1.0 - 1e-9 for a, b in zip([1.2] + stale_in, stale_in))
    assert len([t for t in changes if t > 1.2]) <= 2 * (4.0 - 1.2) + 1    # vs. 11 flips unheld


def test_odometry_comes_from_the_valid_wheels(monkeypatch):
    """Husky, 1 m/s straight: with the left-front wheel NaN the twist comes from the other three
    (flagged, larger variance, never NaN); with no valid wheel the IMU gives the yaw rate and the
    speed is unknown; with neither nothing is published."""
    from test_ros2_interop import LOOPBACK

    from terrainml.stream.transports.ros2.sink import UNKNOWN_VAR, Ros2Sink
    from terrainml.stream.transports.ros2.types import Header

    monkeypatch.setenv("CYCLONEDDS_URI", LOOPBACK)
    robot = load_robot("husky")
    sink = Ros2Sink("ros2://211?desired_slip=&terrain=&diagnostics=", robot)
    try:
        omega = 1.0 / robot.wheel_radius_m

        def sample(bad=(), imu=True):
            s = {"wheels_valid": not bad, "imu_valid": imu, "imu_yaw_rate_radps": 0.1}
            for i in range(1, 5):
                s[f"wheel{i}_omega_radps"] = math.nan if i in bad else omega
                s[f"wheel{i}_steer_rad"] = 0.0
            return s

        def odo(k, s):
            m = _msg(k * 0.01, "estimator_unhealthy", ok=False)
            return sink._odometry(m, s, Header())

        full = odo(0, sample())
        part = odo(1, sample(bad=(1,)))
        assert sink.odometry_note == "from 3 of 4 wheels (wheel1 invalid)"
        assert part.twist.twist.linear.x == pytest.approx(1.0, abs=0.02)
        assert part.twist.covariance[0] > full.twist.covariance[0]
        imu_only = odo(2, sample(bad=(1, 2, 3, 4)))
        assert imu_only.twist.twist.angular.z == pytest.approx(0.1)
        assert imu_only.twist.covariance[0] == UNKNOWN_VAR
        assert all(math.isfinite(v) for v in (imu_only.pose.pose.position.x, imu_only.twist.twist.linear.x))
        assert odo(3, sample(bad=(1, 2, 3, 4), imu=False)) is None
    finally:
        sink.close()


def test_odometry_from_one_side_takes_the_yaw_rate_from_the_imu(monkeypatch):
    """Husky at 1 m/s turning at 0.2 rad/s, both left wheels NaN: with a valid IMU the right wheels
    and the IMU's yaw rate give the speed (flagged, finite, larger variance); without the IMU one
    side cannot tell speed from turning, and the speed is not taken from it."""
    from test_ros2_interop import LOOPBACK

    from terrainml.stream.transports.ros2.sink import UNKNOWN_VAR, Ros2Sink
    from terrainml.stream.transports.ros2.types import Header

    monkeypatch.setenv("CYCLONEDDS_URI", LOOPBACK)
    robot = load_robot("husky")
    sink = Ros2Sink("ros2://212?desired_slip=&terrain=&diagnostics=", robot)
    try:
        vx, r = 1.0, 0.2

        def sample(bad=(), imu=True):
            s = {"wheels_valid": not bad, "imu_valid": imu, "imu_yaw_rate_radps": r}
            for i, w in enumerate(robot.wheels, start=1):
                s[f"wheel{i}_omega_radps"] = math.nan if i in bad else (vx - r * w.y_m) / robot.wheel_radius_m
                s[f"wheel{i}_steer_rad"] = 0.0
            return s

        def odo(k, s):
            return sink._odometry(_msg(k * 0.01, "estimator_unhealthy", ok=False), s, Header())

        full = odo(0, sample())
        right = odo(1, sample(bad=(1, 3)))
        assert sink.odometry_note == "from 2 of 4 wheels (wheel1, wheel3 invalid)"
        assert right.twist.twist.linear.x == pytest.approx(vx, abs=0.02)
        assert right.twist.twist.angular.z == pytest.approx(r, abs=0.01)
        assert full.twist.covariance[0] < right.twist.covariance[0] < UNKNOWN_VAR
        blind = odo(2, sample(bad=(1, 3), imu=False))
        assert blind is None and sink.odometry_note == "2 of 4 wheels valid, on one side, and no IMU: not published"
    finally:
        sink.close()


def test_the_built_in_map_that_fits_the_graph_is_named():
    from terrainml.stream.transports.ros2.source import fitting_maps

    husky = {"/joint_states": "sensor_msgs/msg/JointState", "/imu/data": "sensor_msgs/msg/Imu",
             "/rosout": "rcl_interfaces/msg/Log"}
    assert fitting_maps(husky) == ["husky_ros2"]
    assert fitting_maps({"/imu/data": "sensor_msgs/msg/Imu"}) == []
    assert fitting_maps({**husky, "/imu/data": "std_msgs/msg/Float64"}) == []


def test_a_return_after_total_silence_starts_a_new_timeline_at_once(sand_msgs, monkeypatch):
    """Every topic stops at 3 s; 5 s of wall time later they return (stamps 5 s on), the camera
    delivered 1.5 s ahead of the others: one new timeline, nothing dropped off it."""
    import terrainml.stream.transports.ros2.align as align

    wall = [1000.0]
    monkeypatch.setattr(align.time, "monotonic", lambda: wall[0])
    al = LiveAligner(load_topic_map(None), load_robot(), name="t", warmup_wait_s=0.0)
    t0 = min(int(p["t_ns"][0]) for _, p in sand_msgs)
    rel = [(tp, p, (int(p["t_ns"][0]) - t0) * 1e-9) for tp, p in sand_msgs]
    out = []
    for tp, p, r in rel:
        if r < 3.0:
            wall[0] += 0.001
            al.add(tp, p)
            out += al.poll()
    wall[0] += 5.0
    back = [(tp, p, r) for tp, p, r in rel if r >= 8.0]
    cam = [x for x in back if x[0] == "/camera/odom/sample" and x[2] < 9.5]
    for tp, p, _ in cam + [x for x in back if x not in cam]:
        al.add(tp, p)
        out += al.poll()
    out += al.finish()
    assert al.stats()["timelines"] == 2 and not al.stats()["off_timeline"]
    late = [s for s in out if s["t_s"] > 10.0]
    assert late and all(s["imu_valid"] and s["wheels_valid"] for s in late if s["t_s"] < 11.9)


def test_a_loop_lag_never_makes_a_silent_topic_look_fresh():
    """/imu pauses while /wheels goes on, and the process lags 0.3 s every 0.5 s (a busy machine).
    /imu, overdue when the first lag begins, is silent within its 0.5-s timeout and a lag, and
    stays silent through every later lag. /wheels, on time at every lag, is never silent."""
    clock = Clock()
    w = InputWatch(clock)
    for topic in ("/imu", "/wheels"):
        w.add_topic(topic, "sensor_msgs/msg/JointState")
    for _ in range(200):
        clock.t += 0.01
        w.loop(0.01)
        w.on_message("/imu")
        w.on_message("/wheels")
    paused_at, seen = clock.t, []
    for k in range(400):                      # 4 s of /imu paused
        clock.t += 0.31 if k % 50 == 49 else 0.01
        w.loop(0.01)                          # a 0.3-s lag every 0.5 s
        w.on_message("/wheels")
        st = {s["name"]: s for s in w.statuses()}
        seen.append((clock.t - paused_at, st["terrainml: input /imu"]["level"]))
        assert st["terrainml: input /wheels"]["level"] == 0
    first = next(i for i, (_, level) in enumerate(seen) if level == 1)
    assert seen[first][0] <= 0.5 + 0.31 + 0.02               # its timeout, and a lag at most
    assert all(level == 1 for _, level in seen[first:])
