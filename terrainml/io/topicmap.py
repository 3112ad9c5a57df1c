"""YAML topic maps: which topic and field feeds which canonical column (design §5).

Format (see ``terrainml/io/topicmaps/default.yaml`` and docs/io.md)::

    name: my_robot
    stamp: header | log
    imu_mount: robot | {roll_rad: .., pitch_rad: .., yaw_rad: ..}
    sources:
      - {topic: /imu, type: sensor_msgs/msg/Imu, kind: imu, yaw_from_orientation: true}
      - {topic: /odom, type: nav_msgs/msg/Odometry, kind: t265_odometry, min_confidence: 2}
      - topic: /joints
        type: sensor_msgs/msg/JointState
        kind: joint_state
        columns: {"wheel{i}_omega_radps": {joint: "wheel{i}_drive", field: velocity, resample: previous}}
      - {topic: /cmd_vel, type: geometry_msgs/msg/Twist, kind: twist,
         columns: {cmd_vx_mps: linear.x, cmd_vy_mps: linear.y, cmd_yaw_rate_radps: angular.z}}
      - {topic: /terrain/label, type: std_msgs/msg/UInt8, kind: label}
      - {topic: /sim/ground_truth, type: nav_msgs/msg/Odometry, kind: ground_truth}
      - {topic: /wheel_odom, type: nav_msgs/msg/Odometry, kind: diff_drive_odometry}

Kinds: ``imu`` (IMU group, mount-rotated), ``t265_odometry`` (cam group, :mod:`terrainml.io.t265`),
``joint_state`` (any columns from named joints' position/velocity/effort), ``twist`` (cmd group),
``label`` (terrain), ``ground_truth`` (gt_* pose/twist), ``diff_drive_odometry`` (wheel speeds of a
skid/differential robot from its body twist), ``body_odometry`` (a REP 105 odometry -- twist in the
body frame, e.g. robot_localization's ``/odometry/filtered`` -- as the body-velocity reference: the
camera group's ``cam_*`` columns, read through the robot spec's ``camera`` mount, which for a body
frame odometry sits at the origin; a spec without ``camera`` does not use it), ``array`` (any columns
from a ``std_msgs/msg/Float64MultiArray``'s data by index: ``columns: {"wheel{i}_omega_radps":
{index: 0}}`` puts wheel i at index i - 1; stamped with the log time, or on DDS the writer's source
timestamp, since the message has no header). For CSV/Parquet inputs
a map may instead give
``time_column``, ``time_scale`` (to seconds) and ``columns: {file_column: canonical_column}``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from terrainml._yaml_checks import read_builtin_yaml, read_yaml_file
from terrainml.io import cdr
from terrainml.io.topicmap_names import BUILTIN_MAPS

KINDS = {
    "imu": ("imu",),
    "t265_odometry": ("odometry",),
    "ground_truth": ("odometry",),
    "diff_drive_odometry": ("odometry",),
    "body_odometry": ("odometry",),
    "joint_state": ("joint_state",),
    "twist": ("twist",),
    "label": ("scalar",),
    "array": ("array",),
}
FIELDS = ("position", "velocity", "effort")
TWIST_FIELDS = ("linear.x", "linear.y", "linear.z", "angular.x", "angular.y", "angular.z")


class TopicMapError(ValueError):
    """A topic map is invalid (the message names the file and the entry)."""


@dataclass
class Source:
    topic: str
    type: str
    kind: str
    options: dict[str, Any] = field(default_factory=dict)
    columns: dict[str, Any] = field(default_factory=dict)

    @property
    def decode_kind(self) -> str:
        return KINDS[self.kind][0]


@dataclass
class TopicMap:
    name: str
    sources: list[Source]
    stamp: str = "header"
    imu_mount: Any = "robot"
    table: dict[str, Any] = field(default_factory=dict)   # CSV/Parquet options
    source_file: str = "<builtin>"

    def by_topic(self) -> dict[str, Source]:
        return {s.topic: s for s in self.sources}

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "stamp": self.stamp, "imu_mount": self.imu_mount,
                "sources": [{"topic": s.topic, "type": s.type, "kind": s.kind, **s.options,
                             **({"columns": s.columns} if s.columns else {})} for s in self.sources],
                **self.table}


def _check_array_columns(cols: dict, where: str) -> None:
    """``array`` columns: ``{column: {index: I, resample: linear|previous}}`` (a ``{i}`` template: wheel
    i at ``I + i - 1``)."""
    if not cols:
        raise TopicMapError(f"{where}: an array source needs 'columns'")
    for col, spec in cols.items():
        idx = spec.get("index") if isinstance(spec, dict) else None
        if not isinstance(idx, int) or isinstance(idx, bool) or not 0 <= idx < cdr.ARRAY_WIDTH:
            raise TopicMapError(f"{where}: column {col!r} needs an integer index (0..{cdr.ARRAY_WIDTH - 1})")
        if spec.get("resample", "linear") not in ("linear", "previous"):
            raise TopicMapError(f"{where}: column {col!r}: resample must be linear or previous")


def _parse(data: Any, source: str) -> TopicMap:
    if not isinstance(data, dict):
        raise TopicMapError(f"{source}: a topic map must be a mapping")
    stamp = data.get("stamp", "header")
    if stamp not in ("header", "log"):
        raise TopicMapError(f"{source}: field 'stamp' must be header or log, got {stamp!r}")
    mount = data.get("imu_mount", "robot")
    if mount != "robot":
        if not isinstance(mount, dict) or set(mount) - {"roll_rad", "pitch_rad", "yaw_rad"}:
            raise TopicMapError(f"{source}: field 'imu_mount' must be 'robot' or "
                                "{roll_rad, pitch_rad, yaw_rad}")
        try:
            mount = {k: float(mount.get(k, 0.0)) for k in ("roll_rad", "pitch_rad", "yaw_rad")}
        except (TypeError, ValueError):
            raise TopicMapError(f"{source}: field 'imu_mount' values must be numbers") from None
    sources = []
    for i, s in enumerate(data.get("sources") or []):
        where = f"{source}: sources[{i}]"
        if not isinstance(s, dict) or "topic" not in s or "kind" not in s:
            raise TopicMapError(f"{where} needs 'topic' and 'kind'")
        kind = s["kind"]
        if kind not in KINDS:
            raise TopicMapError(f"{where}: unknown kind {kind!r} (known: {', '.join(KINDS)})")
        type_name = cdr.normalize_type(str(s.get("type", "")))
        cols = s.get("columns") or {}
        if not isinstance(cols, dict):
            raise TopicMapError(f"{where}: 'columns' must be a mapping")
        if kind == "joint_state":
            if not cols:
                raise TopicMapError(f"{where}: a joint_state source needs 'columns'")
            for col, spec in cols.items():
                if not isinstance(spec, dict) or "joint" not in spec or spec.get("field") not in FIELDS:
                    raise TopicMapError(f"{where}: column {col!r} needs joint and field "
                                        f"({'|'.join(FIELDS)})")
                if spec.get("resample", "linear") not in ("linear", "previous"):
                    raise TopicMapError(f"{where}: column {col!r}: resample must be linear or previous")
        if kind == "array":
            _check_array_columns(cols, where)
        if kind == "twist":
            cols = cols or {"cmd_vx_mps": "linear.x", "cmd_vy_mps": "linear.y",
                            "cmd_yaw_rate_radps": "angular.z"}
            for col, fld in cols.items():
                if fld not in TWIST_FIELDS:
                    raise TopicMapError(f"{where}: column {col!r}: field must be one of {TWIST_FIELDS}")
        opts = {k: v for k, v in s.items() if k not in ("topic", "type", "kind", "columns")}
        sources.append(Source(str(s["topic"]), type_name, kind, opts, dict(cols)))
    table = {k: data[k] for k in ("time_column", "time_scale", "columns") if k in data}
    if not sources and not table:
        raise TopicMapError(f"{source}: no 'sources' (and no CSV 'columns')")
    return TopicMap(name=str(data.get("name", Path(source).stem)), sources=sources, stamp=stamp,
                    imu_mount=mount, table=table, source_file=source)


def load_topic_map(spec: str | Path | TopicMap | dict | None = None) -> TopicMap:
    """Load a topic map: None gives the default; a built-in name or a YAML path; a dict is parsed."""
    if isinstance(spec, TopicMap):
        return spec
    if isinstance(spec, dict):
        return _parse(spec, "<dict>")
    name = "default" if spec is None else str(spec)
    if name in BUILTIN_MAPS:
        return _parse(read_builtin_yaml("terrainml.io", "topicmaps", name), f"{name}.yaml")
    path = Path(name)
    data = read_yaml_file(path, TopicMapError,
                          f"{path}: topic map file not found (built-in: {', '.join(BUILTIN_MAPS)})")
    return _parse(data, str(path))
