"""Sink ``ros2://[DOMAIN]``: what terrainml serves, as ROS 2 topics over DDS (docs/ros2.md).

Per served tick (``terrainml predict --sink ros2://0``), stamped with the *sample's* ROS time
(``stamp_origin_ns + t_s`` of a ROS 2 source, else ``t_s`` itself), never wall time:

==========================  ===============================  ===================================================
topic (option)              type                             content
==========================  ===============================  ===================================================
/terrainml/desired_slip     std_msgs/Float64MultiArray       per-wheel desired slip, one message per tick, in
(``desired_slip``)                                           the robot spec's wheel order; ``layout.dim[0]``:
                                                             label ``wheels:NAME1,NAME2,...``, size N, stride N
/terrainml/terrain          vision_msgs/Classification       one hypothesis: served class name and its fused
(``terrain``)                                                (calibrated) probability; ``none``/0 in fallback
/diagnostics                diagnostic_msgs/DiagnosticArray  status ``terrainml: predict`` at 1 Hz of stream
(``diagnostics``)                                            time and on every fallback change: level OK / WARN
                                                             (fallback) / ERROR (estimator unhealthy); values:
                                                             estimator_ok, fallback, fallback_reason,
                                                             classification_age_s, terrain, confidence,
                                                             sensors_used, sensors_valid, rate_<group>_hz
/terrainml/odometry         nav_msgs/Odometry                slip-aware wheel odometry
(``odometry``)                                               (:mod:`terrainml.estimation.slip_odometry`): twist
                                                             in ``base_link``, covariance grown with slip and
                                                             its uncertainty; pose integrated in ``odom``
==========================  ===============================  ===================================================

Options (URL query): each topic key above renames its topic (empty: not published);
``odom_frame`` (default ``odom``), ``base_frame`` (``base_link``). Writers are reliable (the ROS
default profile: best-effort and reliable subscribers both match), keep last :data:`SINK_DEPTH`.

Odometry needs the tick's wheel speeds and steering: the serving loop hands each message over
with its :class:`~terrainml.stream.tick.sample.Sample` (``send(msg, sample)``). A tick whose
wheel group is invalid publishes no odometry (nothing is dead-reckoned from a stale encoder).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from dataclasses import replace
from typing import Any

import numpy as np
from cyclonedds.domain import DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.topic import Topic

from terrainml.estimation.slip_odometry import SlipAwareOdometry
from terrainml.robot import RobotSpec, load_robot
from terrainml.schema import VALID_GROUPS, valid_column, wheel_col
from terrainml.stream.tick.inputs import NO_INPUT_S, InputWatch
from terrainml.stream.tick.message import DesiredSlip
from terrainml.stream.tick.sample import NO_SAMPLE, Sample
from terrainml.stream.transports.ros2.names import dds_topic_name, parse_url, qos_for
from terrainml.stream.transports.ros2.source import STAMP_ORIGIN_KEY
from terrainml.stream.transports.ros2.types import (
    Classification, DiagnosticArray, DiagnosticStatus, Float64MultiArray, Header, KeyValue,
    MultiArrayDimension, MultiArrayLayout, ObjectHypothesis, Odometry, Point, Pose,
    PoseWithCovariance, Quaternion, Time, Twist, TwistWithCovariance, Vector3,
)

log = logging.getLogger("terrainml.stream")

DEFAULT_TOPICS = {"desired_slip": "/terrainml/desired_slip", "terrain": "/terrainml/terrain",
                  "diagnostics": "/diagnostics", "odometry": "/terrainml/odometry"}
SINK_OPTIONS = (*DEFAULT_TOPICS, "odom_frame", "base_frame")
TYPES = {"desired_slip": Float64MultiArray, "terrain": Classification, "diagnostics": DiagnosticArray,
         "odometry": Odometry}
DIAGNOSTICS_PERIOD_S = 1.0
#: writer history: a burst of ticks (a backlog, the end of stream) reaches reliable subscribers whole
SINK_DEPTH = 1000
DIAGNOSTIC_NAME = "terrainml: predict"
OK, WARN, ERROR = 0, 1, 2
#: covariance published for a twist or pose component that is not estimated (vz, roll, pitch ...)
UNKNOWN_VAR = 1e6


def ros_time(t_ns: int) -> Time:
    """``builtin_interfaces/Time`` of ``t_ns`` (ns; negative times clipped to 0)."""
    t_ns = max(int(t_ns), 0)
    return Time(sec=t_ns // 1_000_000_000, nanosec=t_ns % 1_000_000_000)


def _cov6(cov3: np.ndarray) -> list[float]:
    """A 6x6 row-major covariance (x, y, z, roll, pitch, yaw) from the planar 3x3 (x, y, yaw)."""
    out = np.diag([0.0, 0.0, UNKNOWN_VAR, UNKNOWN_VAR, UNKNOWN_VAR, 0.0])
    idx = [0, 1, 5]
    out[np.ix_(idx, idx)] = cov3
    return [float(v) for v in out.reshape(-1)]


class _Rates:
    """Valid samples per second of each sensor group over the last second of stream time."""

    def __init__(self) -> None:
        self.hist: deque[tuple[float, tuple[bool, ...]]] = deque()

    def add(self, t_s: float, sample: dict) -> None:
        self.hist.append((t_s, tuple(bool(sample.get(valid_column(g).name, False)) for g in VALID_GROUPS)))
        while self.hist and self.hist[0][0] < t_s - 1.0:
            self.hist.popleft()

    def rates(self) -> dict[str, float]:
        if len(self.hist) < 2:
            return {g: 0.0 for g in VALID_GROUPS}
        span = max(self.hist[-1][0] - self.hist[0][0], 1e-9)
        counts = np.sum([v for _, v in self.hist], axis=0)
        return {g: float((counts[i] - 1 if counts[i] else 0) / span) for i, g in enumerate(VALID_GROUPS)}


class Ros2Sink:
    """Publish each served tick on the four topics of the module docstring; ``/diagnostics`` on a
    wall-clock timer.

    Parameters
    ----------
    spec : ``ros2://DOMAIN[?options]``.
    robot : RobotSpec or name (wheel names and geometry).
    sensors : the model's sensor groups (before the first tick: ``sensors_used``).
    watch : the live source's :class:`~terrainml.stream.tick.inputs.InputWatch` (one status per input
        topic, mapped groups, silence); None: a fresh one (no input topics, silence judged by ticks).
    period_s : the diagnostics timer's period, s (wall clock).
    """

    def __init__(self, spec: str = "ros2://0", robot: RobotSpec | str | None = None,
                 sensors: list[str] | None = None, watch: InputWatch | None = None,
                 period_s: float = DIAGNOSTICS_PERIOD_S):
        url = parse_url(spec, SINK_OPTIONS)
        self.robot = robot if isinstance(robot, RobotSpec) else load_robot(robot)
        self.name = spec.strip()
        self.sensors = list(sensors) if sensors else []
        self.odom_frame = url.options.get("odom_frame", "odom")
        self.base_frame = url.options.get("base_frame", "base_link")
        self.topics = {k: url.options.get(k, v) for k, v in DEFAULT_TOPICS.items()}
        self.dp = DomainParticipant(url.domain_id)
        qos = qos_for("reliable", SINK_DEPTH)
        self.writers = {k: DataWriter(self.dp, Topic(self.dp, dds_topic_name(name), TYPES[k]), qos=qos)
                        for k, name in self.topics.items() if name}
        names = [w.name for w in self.robot.wheels]
        n = len(names)
        self._layout = MultiArrayLayout(dim=[MultiArrayDimension(f"wheels:{','.join(names)}", n, n)], data_offset=0)
        self.odometry = SlipAwareOdometry(self.robot)
        self._sub_odometry: dict[tuple[bool, ...], SlipAwareOdometry] = {}
        self.odometry_note = ""
        self.watch = watch if watch is not None else InputWatch()
        self.diagnostics = DiagnosticsState(self.robot, self.sensors, self.watch)
        self._rates = self.diagnostics.rates
        self._last_reason: str | None = None
        self._lock = threading.Lock()
        self._timer: threading.Thread | None = None
        self._stop = threading.Event()
        if "diagnostics" in self.writers:
            self._timer = threading.Thread(target=self._diagnostics_loop, args=(float(period_s),),
                                           name="terrainml-diagnostics", daemon=True)
            self._timer.start()

    # ------------------------------------------------------------------ per tick
    def send(self, msg: DesiredSlip, tick_sample: Sample = NO_SAMPLE) -> None:
        sample = tick_sample.columns
        origin = sample.get(STAMP_ORIGIN_KEY, 0)
        stamp_ns = int(origin if isinstance(origin, int) else 0) + int(round(msg.t_s * 1e9))
        header = Header(stamp=ros_time(stamp_ns), frame_id=self.base_frame)
        w = self.writers
        if "desired_slip" in w:
            w["desired_slip"].write(Float64MultiArray(layout=self._layout,
                                                      data=[float(v) for v in msg.slip_desired]))
        if "terrain" in w:
            score = 0.0 if msg.fallback else float(msg.confidence)
            w["terrain"].write(Classification(header=header,
                                              results=[ObjectHypothesis(str(msg.terrain_name), score)]))
        if "odometry" in w:
            odo = self._odometry(msg, sample, header)
            if odo is not None:
                w["odometry"].write(odo)
        with self._lock:    # the timer thread reads the same state
            self.diagnostics.tick(msg, sample, stamp_ns, self.odometry_note)
        if "diagnostics" in w and msg.fallback_reason != self._last_reason:
            self._last_reason = msg.fallback_reason
            self._publish_diagnostics()

    def _diagnostics_loop(self, period_s: float) -> None:
        """``diagnostic_updater``'s timer: one DiagnosticArray per period of wall time, ticks or not."""
        while not self._stop.wait(period_s):
            try:
                self._publish_diagnostics()
            except Exception as exc:  # noqa: BLE001 - the timer must outlive one failed write
                log.warning("%s: /diagnostics not published: %s", self.name, exc)

    def _publish_diagnostics(self) -> None:
        with self._lock:
            writer = self.writers.get("diagnostics")
            if writer is None:
                return
            stamp_ns, statuses = self.diagnostics.statuses()
            writer.write(DiagnosticArray(header=Header(stamp=ros_time(stamp_ns), frame_id=self.base_frame),
                                         status=[_status_msg(st, self.robot.name) for st in statuses]))

    def _odometry(self, msg: DesiredSlip, sample: dict, header: Header) -> Odometry | None:
        """Slip-aware odometry from the wheels whose speed is valid on this tick (all of them:
        the full solution; some, at least one per side or any with a valid IMU yaw rate: theirs,
        with the larger covariance that fewer wheels give, and ``odometry_note`` naming the
        others; none but a valid IMU: zero speed with an unknown variance and the IMU's yaw
        rate). None without the IMU and without valid wheels on both sides."""
        n = self.robot.n_wheels
        omega = [_num(sample.get(wheel_col("omega", i))) for i in range(1, n + 1)]
        steer = [_num(sample.get(wheel_col("steer", i)), 0.0) for i in range(1, n + 1)]
        ok = tuple(math.isfinite(o) and math.isfinite(d) for o, d in zip(omega, steer))
        if not sample.get(valid_column("wheels").name, False) and all(ok):
            ok = (False,) * n    # the group said invalid for a reason the values do not show
        imu_ok = bool(sample.get(valid_column("imu").name, False))
        r = _num(sample.get("imu_yaw_rate_radps")) if imu_ok else math.nan
        r = r if math.isfinite(r) else None
        unobserved = bool(msg.slip_measured_note)
        slip = msg.slip_measured if msg.estimator_ok and not unobserved else None
        if all(ok) and not unobserved:
            self.odometry_note = ""
            est = self.odometry.step(msg.t_s, omega, steer, slip, r)
            twist_cov = est.twist_cov
        elif any(ok) and (self._sides_covered(ok) or r is not None):
            # one side's wheels give the speed once the IMU gives the yaw rate (skid steering
            # makes the yaw rate of one side's wheels alone unknowable)
            keep = [i for i in range(n) if ok[i]]
            bad = [self.robot.wheels[i].name for i in range(n) if not ok[i]]
            self.odometry_note = (f"from {len(keep)} of {n} wheels ({', '.join(bad)} invalid)" if bad else
                                  "raw wheel speeds (slip not observable)")
            # an unobserved slip is an unknown one: its variance widens each wheel's speed
            var = np.full(len(keep), UNOBSERVED_SLIP_VAR) if unobserved or slip is None else None
            sub = self.odometry if not bad else self._sub(ok)
            x, twist_cov = sub.twist([omega[i] for i in keep], [steer[i] for i in keep],
                                     None if slip is None else [slip[i] for i in keep], r, var)
            est = self.odometry.integrate(msg.t_s, x, twist_cov)
        elif r is not None:
            self.odometry_note = "no valid wheel: yaw rate from the IMU, speed unknown"
            cov = np.diag([UNKNOWN_VAR, UNKNOWN_VAR, SIGMA_IMU_YAW_RATE ** 2])
            est = self.odometry.integrate(msg.t_s, np.array([0.0, 0.0, r]), cov)
            twist_cov = cov
        else:
            self.odometry_note = ("no valid wheel or IMU: not published" if not any(ok) else
                                  f"{sum(ok)} of {n} wheels valid, on one side, and no IMU: not published")
            return None
        half = 0.5 * est.yaw_rad
        pose = Pose(position=Point(est.x_m, est.y_m, 0.0),
                    orientation=Quaternion(0.0, 0.0, math.sin(half), math.cos(half)))
        twist = Twist(linear=Vector3(est.vx_mps, est.vy_mps, 0.0), angular=Vector3(0.0, 0.0, est.yaw_rate_radps))
        return Odometry(header=Header(stamp=header.stamp, frame_id=self.odom_frame), child_frame_id=self.base_frame,
                        pose=PoseWithCovariance(pose=pose, covariance=_cov6(est.pose_cov)),
                        twist=TwistWithCovariance(twist=twist, covariance=_cov6(twist_cov)))

    def _sides_covered(self, ok: tuple[bool, ...]) -> bool:
        """At least one valid wheel on each side (y > 0 and y < 0); a robot with wheels on the
        centre line (a tricycle's) needs any one."""
        sides = {int(np.sign(w.y_m)) for w, good in zip(self.robot.wheels, ok) if good}
        need = {int(np.sign(w.y_m)) for w in self.robot.wheels} - {0}
        return need <= sides or 0 in sides

    def _sub(self, ok: tuple[bool, ...]) -> SlipAwareOdometry:
        sub = self._sub_odometry.get(ok)
        if sub is None:
            wheels = tuple(w for w, good in zip(self.robot.wheels, ok) if good)
            sub = self._sub_odometry[ok] = SlipAwareOdometry(replace(self.robot, wheels=wheels))
        return sub

    def close(self) -> None:
        self._stop.set()
        if self._timer is not None:
            self._timer.join(timeout=2.0)
        with self._lock:
            self.writers = {}
            self.dp = None


#: slip variance assumed where slip is not measured (not observable, or the estimator unhealthy
#: on a degraded tick): sigma 0.15, about the traction peak of loose ground
UNOBSERVED_SLIP_VAR = 0.15 ** 2
#: yaw-rate sigma of the IMU when it alone gives the twist (rad/s)
SIGMA_IMU_YAW_RATE = 0.02


def _num(v: Any, default: float = math.nan) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return default
    return float(v)


def _status_msg(st: dict, hardware_id: str) -> DiagnosticStatus:
    return DiagnosticStatus(level=st["level"], name=st["name"], message=st["message"], hardware_id=hardware_id,
                            values=[KeyValue(k, str(v)) for k, v in st["values"].items()])


class DiagnosticsState:
    """What ``/diagnostics`` says: the serving status (first) and one status per input topic.

    Fed per tick (:meth:`tick`), read by the wall-clock timer (:meth:`statuses`); the clock is
    the watch's, so tests drive it by hand.

    Serving status ``terrainml: predict``: when every input has been silent for more than
    :data:`~terrainml.stream.tick.inputs.NO_INPUT_S` (1 s; no input topic message, or no tick for a
    source without topics), level ERROR, "no input for N s", whatever the last tick said; else
    the last tick's: OK "serving CLASS", WARN "fallback: REASON", ERROR "estimator unhealthy",
    unless that tick is more than ``NO_INPUT_S`` old while input arrives (nothing is served: a
    new timeline warms up after a total silence, or the aligner waits for a topic), WARN "no tick
    for N s while input arrives".
    An input topic silent beyond its timeout is its own status at WARN, naming it.
    """

    def __init__(self, robot: RobotSpec, sensors: list[str], watch: InputWatch):
        self.robot, self.sensors, self.watch = robot, list(sensors), watch
        self.rates = _Rates()
        self.msg: DesiredSlip | None = None
        self.sample: dict = {}
        self.stamp_ns: int | None = None
        self.tick_wall_s: float | None = None
        self.odometry_note = ""
        self.started_s = watch.clock()

    def tick(self, msg: DesiredSlip, sample: dict, stamp_ns: int, odometry_note: str = "") -> None:
        self.rates.add(msg.t_s, sample)
        self.msg, self.sample, self.stamp_ns = msg, sample, stamp_ns
        self.tick_wall_s = self.watch.clock()
        self.odometry_note = odometry_note

    def groups(self) -> list[str]:
        """The robot's sensor groups that the source maps: no steering on a fixed-wheel robot."""
        mapped = self.watch.mapped_groups
        return [g for g in VALID_GROUPS if (g != "steer" or self.robot.has_steering)
                and (mapped is None or g in mapped)]

    def silence_s(self, now: float) -> float:
        """How long every input has been silent (wall s)."""
        if self.watch.topics:
            return self.watch.idle_s(now)
        return now - (self.tick_wall_s if self.tick_wall_s is not None else self.started_s)

    def statuses(self) -> tuple[int, list[dict]]:
        """(stamp ns, statuses): the stamp is the last tick's ROS time plus the wall time since."""
        now = self.watch.clock()
        stamp = (time.time_ns() if self.stamp_ns is None else
                 self.stamp_ns + int(round((now - (self.tick_wall_s or now)) * 1e9)))
        return stamp, [self._serving(now)] + self.watch.statuses(now)

    def _serving(self, now: float) -> dict:
        msg, sample = self.msg, self.sample
        groups = self.groups()
        values: dict[str, str] = {}
        silence = self.silence_s(now)
        if msg is not None:
            valid = [g for g in groups if sample.get(valid_column(g).name, False)]
            values = {"estimator_ok": str(bool(msg.estimator_ok)).lower(), "fallback": str(bool(msg.fallback)).lower(),
                      "fallback_reason": msg.fallback_reason,
                      "classification_age_s": f"{msg.classification_age_s:.3f}",
                      "terrain": msg.terrain_name, "confidence": f"{msg.confidence:.3f}",
                      "sensors_used": ",".join(msg.sensors), "sensors_valid": ",".join(valid),
                      "slip_measured": msg.slip_measured_note or "observed",
                      "odometry": self.odometry_note or "all wheels"}
            rates = self.rates.rates()
            values.update({f"rate_{g}_hz": f"{rates[g]:.1f}" for g in groups})
        else:
            values = {"sensors_used": ",".join(self.sensors)}
        values["input_silent_s"] = f"{silence:.1f}"
        tick_age_s = None if self.tick_wall_s is None else now - self.tick_wall_s
        if tick_age_s is not None:
            values["tick_age_s"] = f"{tick_age_s:.1f}"
        values["loop_lags"] = str(self.watch.lags)
        values["max_loop_lag_s"] = f"{self.watch.max_lag_s:.3f}"
        if silence > NO_INPUT_S:
            level, text = ERROR, f"no input for {silence:.1f} s"
            silent = self.watch.silent_text(now)
            if silent:
                text += f" ({silent})"
        elif msg is None:
            level, text = WARN, "waiting for the first tick"
        elif tick_age_s is not None and tick_age_s > NO_INPUT_S:
            # input is back but no tick came yet (a new timeline warms up, or a topic lags): the
            # last tick's status is history, nothing is served
            level, text = WARN, (f"no tick for {tick_age_s:.1f} s while input arrives "
                                 "(a new timeline warms up, or the aligner waits for a topic)")
        else:
            level = ERROR if not msg.estimator_ok else WARN if msg.fallback else OK
            text = ("estimator unhealthy" if not msg.estimator_ok else
                    f"fallback: {msg.fallback_reason}" if msg.fallback else f"serving {msg.terrain_name}")
        return {"level": level, "name": DIAGNOSTIC_NAME, "message": text, "values": values}
