"""Sink ``ros2://[DOMAIN]``: what terrainml serves, as ROS 2 topics over DDS (issue 29; docs/ros2.md).

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

Odometry needs the tick's wheel speeds and steering: the serving loop hands the sample over in
``msg.extra["sample"]``. A tick whose wheel group is invalid publishes no odometry (nothing is
dead-reckoned from a stale encoder).
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np
from cyclonedds.domain import DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.topic import Topic

from terrainml.estimation.slip_odometry import SlipAwareOdometry
from terrainml.robot import RobotSpec, load_robot
from terrainml.schema import VALID_GROUPS, valid_column, wheel_col
from terrainml.stream.message import DesiredSlip
from terrainml.stream.ros2.names import dds_topic_name, parse_url, qos_for
from terrainml.stream.ros2.source import STAMP_ORIGIN_KEY
from terrainml.stream.ros2.types import (Classification, DiagnosticArray, DiagnosticStatus, Float64MultiArray,
                                         Header, KeyValue, MultiArrayDimension, MultiArrayLayout,
                                         ObjectHypothesis, Odometry, Point, Pose, PoseWithCovariance,
                                         Quaternion, Time, Twist, TwistWithCovariance, Vector3)

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
    """Publish each served tick on the four topics of the module docstring."""

    def __init__(self, spec: str = "ros2://0", robot: RobotSpec | str | None = None,
                 sensors: list[str] | None = None):
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
        self._rates = _Rates()
        self._last_diag_t: float | None = None
        self._last_reason: str | None = None

    # ------------------------------------------------------------------ per tick
    def send(self, msg: DesiredSlip) -> None:
        sample = msg.extra.get("sample") or {}
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
        self._rates.add(msg.t_s, sample)
        if "odometry" in w:
            odo = self._odometry(msg, sample, header)
            if odo is not None:
                w["odometry"].write(odo)
        if "diagnostics" in w and self._diagnostics_due(msg):
            w["diagnostics"].write(DiagnosticArray(header=header, status=[self._status(msg, sample)]))

    def _odometry(self, msg: DesiredSlip, sample: dict, header: Header) -> Odometry | None:
        n = self.robot.n_wheels
        if not sample.get(valid_column("wheels").name, False):
            return None
        omega = [sample.get(wheel_col("omega", i), math.nan) for i in range(1, n + 1)]
        steer = [sample.get(wheel_col("steer", i), 0.0) for i in range(1, n + 1)]
        if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in omega + steer):
            return None
        r = sample.get("imu_yaw_rate_radps") if sample.get(valid_column("imu").name, False) else None
        slip = msg.slip_measured if msg.estimator_ok else None
        est = self.odometry.step(msg.t_s, omega, steer, slip, r)
        half = 0.5 * est.yaw_rad
        pose = Pose(position=Point(est.x_m, est.y_m, 0.0),
                    orientation=Quaternion(0.0, 0.0, math.sin(half), math.cos(half)))
        twist = Twist(linear=Vector3(est.vx_mps, est.vy_mps, 0.0), angular=Vector3(0.0, 0.0, est.yaw_rate_radps))
        return Odometry(header=Header(stamp=header.stamp, frame_id=self.odom_frame), child_frame_id=self.base_frame,
                        pose=PoseWithCovariance(pose=pose, covariance=_cov6(est.pose_cov)),
                        twist=TwistWithCovariance(twist=twist, covariance=_cov6(est.twist_cov)))

    def _diagnostics_due(self, msg: DesiredSlip) -> bool:
        due = (self._last_diag_t is None or msg.t_s - self._last_diag_t >= DIAGNOSTICS_PERIOD_S
               or msg.t_s < self._last_diag_t or msg.fallback_reason != self._last_reason)
        if due:
            self._last_diag_t, self._last_reason = msg.t_s, msg.fallback_reason
        return due

    def _status(self, msg: DesiredSlip, sample: dict) -> DiagnosticStatus:
        level = ERROR if not msg.estimator_ok else WARN if msg.fallback else OK
        text = ("estimator unhealthy" if not msg.estimator_ok else
                f"fallback: {msg.fallback_reason}" if msg.fallback else f"serving {msg.terrain_name}")
        valid = [g for g in VALID_GROUPS if sample.get(valid_column(g).name, False)]
        values = {"estimator_ok": str(bool(msg.estimator_ok)).lower(), "fallback": str(bool(msg.fallback)).lower(),
                  "fallback_reason": msg.fallback_reason, "classification_age_s": f"{msg.classification_age_s:.3f}",
                  "terrain": msg.terrain_name, "confidence": f"{msg.confidence:.3f}",
                  "sensors_used": ",".join(self.sensors), "sensors_valid": ",".join(valid)}
        values.update({f"rate_{g}_hz": f"{v:.1f}" for g, v in self._rates.rates().items()})
        return DiagnosticStatus(level=level, name=DIAGNOSTIC_NAME, message=text, hardware_id=self.robot.name,
                                values=[KeyValue(k, v) for k, v in values.items()])

    def close(self) -> None:
        self.writers = {}
        self.dp = None
