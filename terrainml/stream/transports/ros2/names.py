"""ROS 2 names on DDS, the ``ros2://`` URL and the QoS profiles (docs/ros2.md).

The mapping is the one of the ROS 2 design article "Topic and Service name mapping to DDS" as
``rmw_cyclonedds_cpp`` applies it:

* a topic ``/foo/bar`` is the DDS topic ``rt/foo/bar`` (``rt/`` = ROS topic; a relative name is
  taken from the root namespace, as a node in ``/`` would resolve it);
* a message type ``pkg/msg/Type`` is the DDS type ``pkg::msg::dds_::Type_``.

URL: ``ros2://[DOMAIN][?key=value&...]``, ``DOMAIN`` the ROS domain id (``ROS_DOMAIN_ID``,
default 0, 0..232). Query keys are listed by the source and sink that read them.

QoS: :func:`qos_for` gives ``sensor_data`` (best effort, volatile: ``rclcpp::SensorDataQoS``; the
reader keeps the last 100 rather than 5, so a stall of a second at 100 Hz loses nothing -- history
depth is not part of QoS matching) or ``reliable`` (reliable, keep last ``depth``, default 1000, volatile:
the ROS default profile with a queue deep enough to ride out a stall of seconds).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from urllib.parse import parse_qsl

from cyclonedds.core import Policy, Qos
from cyclonedds.util import duration

ROS_TOPIC_PREFIX = "rt"
QOS_PROFILES = ("sensor_data", "reliable")
SENSOR_DATA_DEPTH = 100
RELIABLE_DEPTH = 1000
MAX_DOMAIN_ID = 232


class Ros2NameError(ValueError):
    """A ROS 2 name, type or URL that cannot be mapped (the message names it)."""


def dds_topic_name(topic: str) -> str:
    """``/foo/bar`` -> ``rt/foo/bar``."""
    name = topic.strip()
    if not name or name == "/" or "//" in name or name.endswith("/"):
        raise Ros2NameError(f"{topic!r} is not a ROS 2 topic name")
    return f"{ROS_TOPIC_PREFIX}/{name.lstrip('/')}"


def ros_topic_name(dds_topic: str) -> str | None:
    """``rt/foo/bar`` -> ``/foo/bar``; None for a DDS topic that is not a ROS topic."""
    prefix = ROS_TOPIC_PREFIX + "/"
    return "/" + dds_topic[len(prefix):] if dds_topic.startswith(prefix) else None


def dds_type_name(ros_type: str) -> str:
    """``sensor_msgs/msg/Imu`` (or ``sensor_msgs/Imu``) -> ``sensor_msgs::msg::dds_::Imu_``."""
    parts = ros_type.strip().split("/")
    if len(parts) == 2:
        parts = [parts[0], "msg", parts[1]]
    if len(parts) != 3 or not all(parts):
        raise Ros2NameError(f"{ros_type!r} is not a ROS 2 message type (pkg/msg/Type)")
    pkg, kind, name = parts
    return f"{pkg}::{kind}::dds_::{name}_"


def ros_type_name(dds_type: str) -> str:
    """``sensor_msgs::msg::dds_::Imu_`` -> ``sensor_msgs/msg/Imu`` (other names returned as they are)."""
    parts = dds_type.split("::")
    if len(parts) == 4 and parts[2] == "dds_" and parts[3].endswith("_"):
        return f"{parts[0]}/{parts[1]}/{parts[3][:-1]}"
    return dds_type


def qos_for(profile: str = "sensor_data", depth: int | None = None) -> Qos:
    """Reader/writer QoS of a profile (:data:`QOS_PROFILES`)."""
    if profile == "sensor_data":
        return Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(depth or SENSOR_DATA_DEPTH),
                   Policy.Durability.Volatile)
    if profile == "reliable":
        return Qos(Policy.Reliability.Reliable(duration(milliseconds=100)),
                   Policy.History.KeepLast(depth or RELIABLE_DEPTH), Policy.Durability.Volatile)
    raise Ros2NameError(f"unknown QoS profile {profile!r} (known: {', '.join(QOS_PROFILES)})")


@dataclass
class Ros2Url:
    domain_id: int = 0
    options: dict[str, str] = field(default_factory=dict)


def parse_url(spec: str, known: tuple[str, ...] = ()) -> Ros2Url:
    """``ros2://[DOMAIN][?k=v&...]`` -> :class:`Ros2Url`; a key not in ``known`` is refused."""
    s = spec.strip()
    if s == "ros2":
        return Ros2Url()
    if not s.startswith("ros2://"):
        raise Ros2NameError(f"{spec!r}: expected ros2://[DOMAIN]")
    rest, _, query = s[len("ros2://"):].partition("?")
    rest = rest.rstrip("/")
    try:
        domain = int(rest) if rest else 0
    except ValueError:
        raise Ros2NameError(f"{spec!r}: the domain id must be an integer 0..{MAX_DOMAIN_ID}") from None
    if not 0 <= domain <= MAX_DOMAIN_ID:
        raise Ros2NameError(f"{spec!r}: domain id {domain} out of range 0..{MAX_DOMAIN_ID}")
    opts = dict(parse_qsl(query, keep_blank_values=True))
    unknown = sorted(set(opts) - set(known))
    if unknown:
        raise Ros2NameError(f"{spec!r}: unknown option(s) {', '.join(unknown)} (known: {', '.join(known) or 'none'})")
    return Ros2Url(domain, opts)


def is_ros2_spec(spec: str) -> bool:
    s = spec.strip()
    return s == "ros2" or s.startswith("ros2://")
