"""Canonical-column signals of a decoded log source, and the run table they resample into (design §5).

A *signal* is one canonical column sampled at a source's own stamps (seconds from the log's first
message) with its resampling method and gap threshold. :func:`signals_for` turns a time slice of a
decoded source (a :mod:`terrainml.io.cdr` part) into signals; :func:`assemble` resamples signals
onto a slice of the base-rate grid and adds the ``{group}_valid`` columns. The ingest engine
(:mod:`terrainml.io.ingest.logs`) calls both chunk by chunk; CSV/Parquet tables call
:func:`assemble` once.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from terrainml.io import t265
from terrainml.io.ingest.resample import _EPS, resample
from terrainml.io.topicmap import Source, TopicMap
from terrainml.robot import RobotSpec
from terrainml.schema import VALID_GROUPS, WHEEL_STATES, column_map, valid_column, wheel_col

# columns that do not take part in their group's validity
_NOT_IN_VALIDITY = {"imu_yaw_rad", "imu_roll_rate_radps", "imu_pitch_rate_radps", "cam_confidence"}
PREVIOUS_COLUMNS = ("_omega_radps", "_steer_rad")   # sample-and-hold by default (joint_state)
# optional columns a log table always carries (NaN, group invalid, when the source is absent)
_ALWAYS = {"cam_vx_mps", "cam_vy_mps", "cam_yaw_rate_radps", "cam_yaw_rad",
           "cmd_vx_mps", "cmd_vy_mps", "cmd_yaw_rate_radps"}


@dataclass
class Signal:
    column: str
    t_s: np.ndarray                  # (n,) sorted unique stamps, s from the log's first message
    values: np.ndarray               # (n,)
    method: str                      # resample method: linear, previous, angle
    max_gap_s: float
    extra_invalid: np.ndarray | None = None   # (n,) per-sample flag (e.g. low camera confidence)
    period_s: float | None = None    # labels: the regular stream's period (None: held without limit)


@dataclass
class SourceFacts:
    """Whole-log facts of one source that a time slice of it cannot tell (taken by the scan)."""

    gap_s: float                          # gap threshold of the source's stamps
    imu_orientation: bool = True          # the IMU ever publishes an orientation
    cam_yaw0_rad: float | None = None     # raw T265 yaw of the first valid pose
    label_period_s: float | None = None   # a regular label stream's period (None: on change, unknown)


@dataclass
class JointColumn:
    """One canonical column of a joint_state source: which joint and message field feed it."""

    column: str
    joint: str
    field: str                            # position, velocity or effort
    method: str


def joint_columns(src: Source, n_wheels: int) -> list[JointColumn]:
    """Columns of a joint_state source in topic-map order (``{i}`` templates expanded per wheel)."""
    cols = []
    for template, spec in src.columns.items():
        for i in range(1, n_wheels + 1) if "{i}" in template else [None]:
            col = template.replace("{i}", str(i)) if i else template
            joint = spec["joint"].replace("{i}", str(i)) if i else spec["joint"]
            method = spec.get("resample", "previous" if col.endswith(PREVIOUS_COLUMNS) else "linear")
            cols.append(JointColumn(col, joint, spec["field"], method))
    return cols


@functools.lru_cache(maxsize=32)
def _mount(roll_rad: float, pitch_rad: float, yaw_rad: float) -> tuple[Rotation, Rotation]:
    """The IMU mount rotation and its inverse, made once per mount (live streams convert a message
    or two per call, and making the rotation costs as much as applying it)."""
    rot = Rotation.from_euler("xyz", [roll_rad, pitch_rad, yaw_rad])
    return rot, rot.inv()


def _imu_mount(robot: RobotSpec, tmap: TopicMap) -> tuple[Rotation, Rotation]:
    m = tmap.imu_mount
    if m == "robot":
        m = {"roll_rad": robot.imu.roll_rad, "pitch_rad": robot.imu.pitch_rad, "yaw_rad": robot.imu.yaw_rad}
    return _mount(float(m["roll_rad"]), float(m["pitch_rad"]), float(m["yaw_rad"]))


def array_columns(src: Source, n_wheels: int) -> list[tuple[str, int, str]]:
    """(column, index, method) of an ``array`` source in topic-map order (``{i}`` expanded per wheel:
    wheel i at the entry's index + i - 1)."""
    cols = []
    for template, spec in src.columns.items():
        for i in range(1, n_wheels + 1) if "{i}" in template else [None]:
            col = template.replace("{i}", str(i)) if i else template
            method = spec.get("resample", "previous" if col.endswith(PREVIOUS_COLUMNS) else "linear")
            cols.append((col, int(spec["index"]) + (i - 1 if i else 0), method))
    return cols


def imu_rotation(robot: RobotSpec, tmap: TopicMap) -> Rotation:
    return _imu_mount(robot, tmap)[0]


def _yaw_of(q: np.ndarray, min_norm: float, rot_inv: Rotation | None = None) -> np.ndarray:
    """Yaw (ZYX) of quaternions (n, 4) xyzw, in the frame of ``rot_inv``'s inverse when given; NaN
    where a quaternion is non-finite or ~zero."""
    ok = np.isfinite(q).all(axis=1) & (np.linalg.norm(np.nan_to_num(q), axis=1) > min_norm)
    r = Rotation.from_quat(np.where(ok[:, None], q, [0.0, 0.0, 0.0, 1.0]))
    return np.where(ok, (r if rot_inv is None else r * rot_inv).as_euler("ZYX")[:, 0], np.nan)


def signals_for(src: Source, part: dict, t_s: np.ndarray, robot: RobotSpec, tmap: TopicMap,
                facts: SourceFacts) -> list[Signal]:
    """Canonical-column signals of one sorted time slice ``part`` of a (non joint_state) source."""
    sig: list[Signal] = []

    def add(col, values, method="linear", extra=None):
        sig.append(Signal(col, t_s, np.asarray(values, float), method, facts.gap_s, extra))

    kind = src.kind
    if kind == "imu":
        rot, rot_inv = _imu_mount(robot, tmap)
        acc = rot.apply(part["accel"])
        gyr = rot.apply(part["gyro"])
        for j, axis in enumerate("xyz"):
            add(f"imu_a{axis}_mps2", acc[:, j])
        for j, name in enumerate(("roll", "pitch", "yaw")):
            add(f"imu_{name}_rate_radps", gyr[:, j])
        # an IMU without orientation publishes identity (or zeros) throughout: no yaw column then
        if src.options.get("yaw_from_orientation", True) and facts.imu_orientation:
            add("imu_yaw_rad", _yaw_of(part["orientation"], 1e-6, rot_inv), "angle")
    elif kind == "t265_odometry":
        out = t265.t265_odometry_to_body(part["position"], part["orientation"], part["linear"],
                                         part["angular"], positions=False)
        conf = part["cov0"]
        min_conf = src.options.get("min_confidence", 2)
        low = None if min_conf is None else ~(conf >= float(min_conf))
        add("cam_vx_mps", out["vx_mps"], extra=low)
        add("cam_vy_mps", out["vy_mps"], extra=low)
        add("cam_yaw_rate_radps", out["yaw_rate_radps"], extra=low)
        yaw = out["yaw_rad"] if facts.cam_yaw0_rad is None else \
            t265.wrap_angle(out["yaw_raw_rad"] - facts.cam_yaw0_rad)
        add("cam_yaw_rad", yaw, "angle", extra=low)
        add("cam_confidence", conf, "previous")
    elif kind == "ground_truth":
        add("gt_x_m", part["position"][:, 0])
        add("gt_y_m", part["position"][:, 1])
        add("gt_yaw_rad", _yaw_of(part["orientation"], 1e-9), "angle")
        add("gt_vx_mps", part["linear"][:, 0])
        add("gt_vy_mps", part["linear"][:, 1])
        add("gt_yaw_rate_radps", part["angular"][:, 2])
    elif kind == "body_odometry":   # REP 105: twist in the child (body) frame; yaw of the odom pose
        add("cam_vx_mps", part["linear"][:, 0])
        add("cam_vy_mps", part["linear"][:, 1])
        add("cam_yaw_rate_radps", part["angular"][:, 2])
        add("cam_yaw_rad", _yaw_of(part["orientation"], 1e-9), "angle")
    elif kind == "diff_drive_odometry":
        v, w = part["linear"][:, 0], part["angular"][:, 2]
        track = 2.0 * float(np.mean([abs(wh.y_m) for wh in robot.wheels]))
        for i, wh in enumerate(robot.wheels, start=1):
            side = -1.0 if wh.y_m > 0 else 1.0          # left wheels: v - w * track / 2
            add(wheel_col("omega", i), (v + side * w * track / 2.0) / robot.wheel_radius_m)
            add(wheel_col("steer", i), np.zeros_like(v))
    elif kind == "twist":
        for col, fld in src.columns.items():
            grp, axis = fld.split(".")
            add(col, part[grp][:, "xyz".index(axis)])
    elif kind == "array":   # a value the message does not have is NaN (the tick invalid)
        data, width = part["data"], part["width"]
        for col, idx, method in array_columns(src, robot.n_wheels):
            add(col, np.where(width > idx, data[:, min(idx, data.shape[1] - 1)], np.nan), method)
    elif kind == "label":
        add("terrain", part["data"], "previous")
        # a regular label stream has holes of its own (a gap over its threshold); on change: none
        sig[-1].period_s = facts.label_period_s
        sig[-1].max_gap_s = np.inf if facts.label_period_s is None else facts.gap_s
    return sig


def label_stream_stale(s: Signal, grid: np.ndarray) -> np.ndarray:
    """Ticks of ``grid`` whose label is stale because of a hole in the label stream itself.

    A regular label stream (``s.period_s`` set) has a hole wherever two consecutive label samples
    are more than ``s.max_gap_s`` apart (its gap threshold), or after its last sample. Across such
    a hole the held label lasts one period -- as far as it would have in the complete stream --
    and the ticks after it are stale until the next label sample, whatever the other sensors do.
    ``s.t_s`` must hold the first sample after ``grid`` when there is one within the threshold.

    Parameters
    ----------
    s : Signal
        The ``terrain`` signal.
    grid : numpy.ndarray
        (m,) tick times (s).

    Returns
    -------
    numpy.ndarray
        (m,) bool, True where the label is stale.
    """
    if s.period_s is None or not len(s.t_s):
        return np.zeros(len(grid), bool)
    i = np.searchsorted(s.t_s, grid + _EPS, side="right") - 1
    held = s.t_s[np.clip(i, 0, None)]
    nxt = np.append(s.t_s[1:], np.inf)[np.clip(i, 0, None)]
    hole = nxt - held > s.max_gap_s + _EPS
    return (i >= 0) & hole & (grid - held > s.period_s + _EPS)


def last_hole_s(df: pd.DataFrame, before_s: float = -np.inf) -> float:
    """Time (s) of the last tick of ``df`` in a hole -- no sensor group valid -- or ``before_s``."""
    alive = np.logical_or.reduce([df[valid_column(g).name].to_numpy(bool) for g in VALID_GROUPS])
    dead = df["t_s"].to_numpy(float)[~alive]
    return float(dead[-1]) if len(dead) else before_s


def filled_columns(present: list[str], robot: RobotSpec, spec: dict) -> tuple[list[str], list[str]]:
    """Columns a table gets without a signal: the steering of fixed wheels (known zero, valid) and
    the required and always-present columns no source feeds (NaN, invalid)."""
    zeros = [wheel_col("steer", i) for i, wh in enumerate(robot.wheels, start=1)
             if not wh.steerable and wheel_col("steer", i) not in present]
    absent = [c.name for c in spec.values() if (c.required or c.name in _ALWAYS) and c.name not in present
              and c.name not in zeros]
    return zeros, absent


def validity_members(columns: list[str], spec: dict) -> dict[str, list[str]]:
    """Per sensor group (``VALID_GROUPS`` order): which of ``columns`` make its ``{group}_valid``."""
    return {g: [c for c in columns if c in spec and spec[c].group == g and c not in _NOT_IN_VALIDITY
                and not c.endswith("_cmd_omega_radps")] for g in VALID_GROUPS}


def assemble(signals: list[Signal], grid: np.ndarray, robot: RobotSpec,
             hole_before_s: float = -np.inf) -> pd.DataFrame:
    """Resample ``signals`` onto ``grid`` (m,) s: the canonical columns, each ``{group}_valid``.

    Labels are held from one label sample to the next, but never across a hole: a tick at which
    no sensor group is valid (a corrupt chunk, a cut, every sensor silent), or a hole in the label
    stream itself (:func:`label_stream_stale`). Ticks in a hole and after it get no label (-1)
    until a new label sample; ``hole_before_s`` is the last hole tick before ``grid`` (chunked
    ingest, :func:`last_hole_s`).
    """
    spec = column_map(robot.n_wheels)
    data: dict[str, np.ndarray] = {"t_s": grid}
    col_valid: dict[str, np.ndarray] = {}
    label_t = None
    while signals:
        s = signals.pop(0)  # release each source signal once resampled (bounded peak memory)
        held = s.column.startswith("gt_state") or s.column == "terrain"
        if s.column == "terrain":   # stamp of the label sample each tick holds
            i = np.searchsorted(s.t_s, grid + _EPS, side="right") - 1
            label_t = np.where(i >= 0, s.t_s[np.clip(i, 0, None)] if len(s.t_s) else 0.0, np.inf)
        out, valid = resample(s.t_s, s.values, grid, method="previous" if held else s.method,
                              max_gap_s=np.inf if s.column == "terrain" else s.max_gap_s)
        if s.column == "terrain":
            out = np.where(label_stream_stale(s, grid), np.nan, out)
        if s.extra_invalid is not None and len(s.t_s):
            low, _ = resample(s.t_s, s.extra_invalid.astype(float), grid, method="previous", max_gap_s=np.inf)
            valid = valid & ~(low > 0.5)
        data[s.column] = out
        col_valid[s.column] = valid
    m = len(grid)
    zeros, absent = filled_columns(list(data), robot, spec)
    for c in zeros:
        data[c] = np.zeros(m)
        col_valid[c] = np.ones(m, bool)
    for c in absent:
        data[c] = np.full(m, np.nan)
        col_valid[c] = np.zeros(m, bool)
    for g, members in validity_members(list(col_valid), spec).items():  # False when the group is absent
        data[valid_column(g).name] = (np.logical_and.reduce([col_valid[c] for c in members]) if members
                                      else np.zeros(m, bool))
    if "terrain" in data:
        t = data["terrain"]
        if label_t is not None:
            alive = np.logical_or.reduce([data[valid_column(g).name] for g in VALID_GROUPS])
            last_dead = np.maximum.accumulate(np.maximum(np.where(alive, -np.inf, grid), hole_before_s))
            t = np.where(last_dead > label_t + _EPS, np.nan, t)
        data["terrain"] = np.where(np.isfinite(t), np.nan_to_num(t, nan=-1), -1).astype(np.int64)
    for c in [c for c in data if c.startswith("gt_state")]:
        data[c] = _codes_to_states(data[c])
    ordered = [c.name for c in spec.values() if c.name in data]
    ordered += [k for k in data if k not in ordered]
    return pd.DataFrame({k: data.pop(k) for k in ordered}, copy=False)


def _codes_to_states(codes: np.ndarray) -> np.ndarray:
    """``/sim/wheel_state`` codes (``topics.WHEEL_STATE_CODES``, WHEEL_STATES order) -> names."""
    names = np.array(list(WHEEL_STATES) + ["unknown"], dtype=object)
    idx = np.where(np.isfinite(codes), np.nan_to_num(codes, nan=4), 4).astype(int)
    return names[np.where((idx >= 0) & (idx < 4), idx, 4)]
