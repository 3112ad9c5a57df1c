"""Log ingest: ROS 2 MCAP, ROS 1 bag, CSV or Parquet -> canonical run table (SYSTEM §5, contract 1).

``load_run(path, robot=None, topic_map=None, rate_hz=100.0) -> IngestResult`` with ``.table`` (a
validated canonical DataFrame, metadata in ``attrs["terrainml"]``; zero rows when nothing usable
was found) and ``.report`` (per-topic counts, warnings, ``usable``).

Never raises on bad input: damage is counted per topic and reported; the report's ``errors`` say
why a file gave no usable table. ``write_run_mcap`` writes a run table back to a ROS 2 MCAP with
the default topic map's messages, so a hand-made table round-trips.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from terrainml.io import cdr, t265, topics
from terrainml.io.readers import LogReadError, ReadResult, read_bag, read_mcap, sniff_format
from terrainml.io.resample import clean_times, gap_threshold_s, resample
from terrainml.io.topicmap import Source, TopicMap, TopicMapError, load_topic_map
from terrainml.robot import RobotSpec, RobotSpecError, load_robot
from terrainml.schema import (DEFAULT_RATE_HZ, VALID_GROUPS, WHEEL_STATES, SchemaError, column_map,
                              make_metadata, validate_run_table)

# columns that do not take part in their group's validity
_NOT_IN_VALIDITY = {"imu_yaw_rad", "imu_roll_rate_radps", "imu_pitch_rate_radps", "cam_confidence"}
_PREVIOUS_COLUMNS = ("_omega_radps", "_steer_rad")
_CODE_TO_STATE = {v: k for k, v in topics.WHEEL_STATE_CODES.items()}


@dataclass
class IngestReport:
    """What ingest found: per-topic counts, warnings, and whether a usable table resulted."""

    source: str
    format: str = ""
    topics: dict[str, dict[str, Any]] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)   # e.g. optional topics absent
    usable: bool = False
    rows: int = 0
    span_s: float = 0.0
    rate_hz: float = DEFAULT_RATE_HZ
    valid_fraction: dict[str, float] = field(default_factory=dict)

    def skipped_per_topic(self) -> dict[str, int]:
        return {t: d["skipped"] for t, d in self.topics.items() if d.get("skipped")}

    def corrupt_per_topic(self) -> dict[str, int]:
        return {t: d["corrupt"] for t, d in self.topics.items() if d.get("corrupt")}

    def to_dict(self) -> dict[str, Any]:
        return {"source": self.source, "format": self.format, "usable": self.usable, "rows": self.rows,
                "span_s": self.span_s, "rate_hz": self.rate_hz, "topics": self.topics,
                "valid_fraction": self.valid_fraction, "warnings": self.warnings, "errors": self.errors,
                "notes": self.notes}


@dataclass
class IngestResult:
    table: pd.DataFrame
    report: IngestReport


@dataclass
class _Signal:
    column: str
    t_s: np.ndarray
    values: np.ndarray
    method: str
    max_gap_s: float
    extra_invalid: np.ndarray | None = None   # per-sample flag (e.g. low confidence)


# ----------------------------------------------------------------------------- helpers
def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _imu_rotation(robot: RobotSpec, tmap: TopicMap) -> Rotation:
    m = tmap.imu_mount
    if m == "robot":
        m = {"roll_rad": robot.imu.roll_rad, "pitch_rad": robot.imu.pitch_rad, "yaw_rad": robot.imu.yaw_rad}
    return Rotation.from_euler("xyz", [m["roll_rad"], m["pitch_rad"], m["yaw_rad"]])


def _expand(template: str, i: int) -> str:
    return template.replace("{i}", str(i))


def _empty_table(robot: RobotSpec) -> pd.DataFrame:
    cols = {c.name: pd.Series([], dtype="float64") for c in column_map(robot.n_wheels).values() if c.required}
    return validate_run_table(pd.DataFrame(cols), robot.n_wheels)


# ----------------------------------------------------------------------------- per-kind signals
def _sorted_part(part: dict, topic: str, rep: IngestReport, t0_ns: int) -> tuple[dict, np.ndarray]:
    order, ooo, dup = clean_times(part["t_ns"])
    d = rep.topics[topic]
    d["out_of_order"] = d.get("out_of_order", 0) + ooo
    d["duplicates"] = d.get("duplicates", 0) + dup
    if ooo == 0 and dup == 0:
        out = part  # already in order: no copy
    else:
        out = {k: (v[order] if isinstance(v, np.ndarray) else v) for k, v in part.items()}
    return out, (out["t_ns"] - t0_ns) * 1e-9


def _signals_for(src: Source, part: dict, t_s: np.ndarray, robot: RobotSpec, tmap: TopicMap,
                 rate_hz: float, *, gap_s: float | None = None, imu_orientation: bool | None = None,
                 cam_yaw0_rad: float | None = None) -> list[_Signal]:
    """Canonical-column signals of one sorted source part.

    The keyword arguments carry whole-log facts when ``part`` is only a time slice of the source
    (streaming ingest): ``gap_s`` the source's gap threshold, ``imu_orientation`` whether the IMU
    ever publishes an orientation, ``cam_yaw0_rad`` the raw T265 yaw of the first valid pose. None:
    computed from ``part`` itself (the whole source, in-memory path).
    """
    gap = gap_threshold_s(t_s, rate_hz) if gap_s is None else float(gap_s)
    sig: list[_Signal] = []

    def add(col, values, method="linear", extra=None):
        sig.append(_Signal(col, t_s, np.asarray(values, float), method, gap, extra))

    kind = src.kind
    if kind == "imu":
        rot = _imu_rotation(robot, tmap)
        acc = rot.apply(part["accel"])
        gyr = rot.apply(part["gyro"])
        add("imu_ax_mps2", acc[:, 0]); add("imu_ay_mps2", acc[:, 1]); add("imu_az_mps2", acc[:, 2])
        add("imu_roll_rate_radps", gyr[:, 0]); add("imu_pitch_rate_radps", gyr[:, 1])
        add("imu_yaw_rate_radps", gyr[:, 2])
        q = part["orientation"]
        if src.options.get("yaw_from_orientation", True):
            norm = np.linalg.norm(np.nan_to_num(q), axis=1)
            never_set = _imu_orientation_never_set(q) if imu_orientation is None else not imu_orientation
            if not never_set:  # an IMU without orientation publishes identity (or zeros) throughout
                ok = np.isfinite(q).all(axis=1) & (norm > 1e-6)
                qs = np.where(ok[:, None], q, [0.0, 0.0, 0.0, 1.0])
                yaw = (Rotation.from_quat(qs) * rot.inv()).as_euler("ZYX")[:, 0]
                add("imu_yaw_rad", np.where(ok, yaw, np.nan), "angle")
    elif kind == "t265_odometry":
        out = t265.t265_odometry_to_body(part["position"], part["orientation"], part["linear"],
                                         part["angular"])
        conf = part["cov0"]
        min_conf = src.options.get("min_confidence", 2)
        low = None if min_conf is None else ~(conf >= float(min_conf))
        add("cam_vx_mps", out["vx_mps"], extra=low)
        add("cam_vy_mps", out["vy_mps"], extra=low)
        add("cam_yaw_rate_radps", out["yaw_rate_radps"], extra=low)
        yaw = out["yaw_rad"] if cam_yaw0_rad is None else t265.wrap_angle(out["yaw_raw_rad"] - cam_yaw0_rad)
        add("cam_yaw_rad", yaw, "angle", extra=low)
        add("cam_confidence", conf, "previous")
    elif kind == "ground_truth":
        q = part["orientation"]
        ok = np.isfinite(q).all(axis=1) & (np.linalg.norm(np.nan_to_num(q), axis=1) > 1e-9)
        qs = np.where(ok[:, None], q, [0.0, 0.0, 0.0, 1.0])
        yaw = np.where(ok, Rotation.from_quat(qs).as_euler("ZYX")[:, 0], np.nan)
        add("gt_x_m", part["position"][:, 0]); add("gt_y_m", part["position"][:, 1])
        add("gt_yaw_rad", yaw, "angle")
        add("gt_vx_mps", part["linear"][:, 0]); add("gt_vy_mps", part["linear"][:, 1])
        add("gt_yaw_rate_radps", part["angular"][:, 2])
    elif kind == "diff_drive_odometry":
        v, w = part["linear"][:, 0], part["angular"][:, 2]
        track = 2.0 * float(np.mean([abs(wh.y_m) for wh in robot.wheels]))
        for i, wh in enumerate(robot.wheels, start=1):
            side = -1.0 if wh.y_m > 0 else 1.0          # left wheels: v - w * track / 2
            add(f"wheel{i}_omega_radps", (v + side * w * track / 2.0) / robot.wheel_radius_m)
            add(f"wheel{i}_steer_rad", np.zeros_like(v))
    elif kind == "twist":
        for col, fld in src.columns.items():
            grp, axis = fld.split(".")
            add(col, part[grp][:, "xyz".index(axis)])
    elif kind == "label":
        add("terrain", part["data"], "previous")
        sig[-1].max_gap_s = np.inf
    return sig


def _imu_orientation_never_set(q: np.ndarray) -> bool:
    """An IMU without orientation publishes identity (or zeros) throughout."""
    qf = np.nan_to_num(q)
    return bool(np.allclose(qf, [0.0, 0.0, 0.0, 1.0]) or np.allclose(qf, 0.0))


def _joint_signals(src: Source, parts: list[dict], t0_ns: int, robot: RobotSpec, rate_hz: float,
                   rep: IngestReport) -> list[_Signal]:
    """Columns of a joint_state source; each column collects samples from every joint-name set."""
    sig = []
    for template, spec in src.columns.items():
        for i in range(1, robot.n_wheels + 1) if "{i}" in template else [None]:
            col = _expand(template, i) if i else template
            joint = _expand(spec["joint"], i) if i else spec["joint"]
            ts, vs = [], []
            for p in parts:
                if joint in p["names"]:
                    k = p["names"].index(joint)
                    ts.append(p["t_ns"])
                    vs.append(p[spec["field"]][:, k])
            if not ts:
                rep.warnings.append(f"{rep.source}: topic {src.topic}: no joint '{joint}' for column {col}")
                continue
            t = np.concatenate(ts)
            v = np.concatenate(vs)
            order, _, _ = clean_times(t)
            t_s = (t[order] - t0_ns) * 1e-9
            method = spec.get("resample", "previous" if col.endswith(_PREVIOUS_COLUMNS) else "linear")
            gap = np.inf if col.startswith("gt_state") else gap_threshold_s(t_s, rate_hz)
            sig.append(_Signal(col, t_s, v[order], method, gap))
    return sig


# ----------------------------------------------------------------------------- table assembly
def _assemble(signals: list[_Signal], grid: np.ndarray, robot: RobotSpec, rep: IngestReport) -> pd.DataFrame:
    n = robot.n_wheels
    spec = column_map(n)
    data: dict[str, np.ndarray] = {"t_s": grid}
    col_valid: dict[str, np.ndarray] = {}
    while signals:
        s = signals.pop(0)  # release each source signal once resampled (bounded peak memory)
        vals = s.values
        if s.column.startswith("gt_state") or s.column == "terrain":
            out, valid = resample(s.t_s, vals, grid, method="previous", max_gap_s=s.max_gap_s)
        else:
            out, valid = resample(s.t_s, vals, grid, method=s.method, max_gap_s=s.max_gap_s)
        if s.extra_invalid is not None and len(s.t_s):
            low, _ = resample(s.t_s, s.extra_invalid.astype(float), grid, method="previous",
                              max_gap_s=np.inf)
            valid = valid & ~(low > 0.5)
        data[s.column] = out
        col_valid[s.column] = valid
    m = len(grid)
    # fixed wheels: steering is known to be zero
    for i, wh in enumerate(robot.wheels, start=1):
        c = f"wheel{i}_steer_rad"
        if c not in data and not wh.steerable:
            data[c] = np.zeros(m)
            col_valid[c] = np.ones(m, bool)
    always = {"cam_vx_mps", "cam_vy_mps", "cam_yaw_rate_radps", "cam_yaw_rad",
              "cmd_vx_mps", "cmd_vy_mps", "cmd_yaw_rate_radps"}
    for c in spec.values():
        if (c.required or c.name in always) and c.name not in data:
            data[c.name] = np.full(m, np.nan)
            col_valid[c.name] = np.zeros(m, bool)
    for g in VALID_GROUPS:  # every group gets its validity column (False when the group is absent)
        members = [c for c in col_valid if c in spec and spec[c].group == g and c not in _NOT_IN_VALIDITY
                   and not c.endswith("_cmd_omega_radps")]
        data[f"{g}_valid"] = (np.logical_and.reduce([col_valid[c] for c in members]) if members
                              else np.zeros(m, bool))
    if "terrain" in data:
        t = data["terrain"]
        data["terrain"] = np.where(np.isfinite(t), np.nan_to_num(t, nan=-1), -1).astype(np.int64)
    for i in range(1, n + 1):
        c = f"gt_state{i}"
        if c in data:
            codes = data[c]
            data[c] = np.array([_CODE_TO_STATE.get(int(x), "unknown") if np.isfinite(x) else "unknown"
                                for x in codes], dtype=object) if m < 50_000 else \
                _codes_to_states_fast(codes)
    ordered = [c.name for c in spec.values() if c.name in data]
    ordered += [k for k in data if k not in ordered]
    return pd.DataFrame({k: data.pop(k) for k in ordered}, copy=False)


def _codes_to_states_fast(codes: np.ndarray) -> np.ndarray:
    names = np.array(list(WHEEL_STATES) + ["unknown"], dtype=object)
    idx = np.where(np.isfinite(codes), np.nan_to_num(codes, nan=4), 4).astype(int)
    idx = np.where((idx >= 0) & (idx < 4), idx, 4)
    return names[idx]


# ----------------------------------------------------------------------------- logs
def _wanted_for(tmap: TopicMap) -> tuple[Callable[[str, str], str | None], dict[str, str]]:
    """The reader's ``wanted(topic, type) -> decode kind`` for a topic map, and the dict it fills
    with mapped topics whose type does not match."""
    by_topic = tmap.by_topic()
    mismatched: dict[str, str] = {}

    def wanted(topic: str, type_name: str) -> str | None:
        src = by_topic.get(topic)
        if src is None:
            return None
        expected = src.type
        if (expected and type_name != expected) or cdr.KIND_OF_TYPE.get(type_name) != src.decode_kind:
            mismatched[topic] = type_name
            return None
        return src.decode_kind

    return wanted, mismatched


def _read_log(path: Path, fmt: str, tmap: TopicMap, wanted, progress=None, on_part=None,
              validate_crcs: bool = True) -> ReadResult:
    use_header = tmap.stamp == "header"
    if fmt == "mcap":
        return read_mcap(path, wanted, use_header_stamp=use_header, progress=progress, on_part=on_part,
                         validate_crcs=validate_crcs)
    return read_bag(path, wanted, use_header_stamp=use_header, progress=progress, on_part=on_part)


def _report_read(path: Path, res: ReadResult, tmap: TopicMap, mismatched: dict[str, str],
                 rep: IngestReport) -> None:
    """Per-topic counts and the reader's warnings into the report (shared by both ingest paths)."""
    by_topic = tmap.by_topic()
    rep.warnings.extend(res.warnings)
    for topic, st in res.stats.items():
        rep.topics[topic] = {"type": st.type, "mapped": topic in by_topic, "read": st.read,
                             "decoded": st.decoded, "corrupt": st.corrupt, "skipped": st.skipped,
                             "out_of_order": 0, "duplicates": 0, "non_finite": 0}
        if st.corrupt:
            rep.warnings.append(f"{path}: topic {topic}: {st.corrupt} corrupt message(s) skipped")
    if res.unattributed_corrupt:
        rep.topics.setdefault("<unknown channel>", {"type": "", "mapped": False, "read": 0, "decoded": 0,
                                                    "corrupt": res.unattributed_corrupt, "skipped": 0})
    for topic, type_name in mismatched.items():
        src = by_topic[topic]
        rep.warnings.append(f"{path}: topic {topic} has type {type_name}, the topic map expects "
                            f"{src.type or src.decode_kind}: {res.stats[topic].read} message(s) skipped")
    for src in tmap.sources:
        if src.topic not in res.stats:
            (rep.notes if src.options.get("optional") else rep.warnings).append(f"{path}: mapped topic {src.topic} ({src.type or src.kind}) is not in the log")


def _no_message_error(path: Path, tmap: TopicMap) -> str:
    return (f"{path}: no readable message on any mapped topic "
            f"({', '.join(s.topic for s in tmap.sources)}); `terrainml inspect` lists the "
            "log's topics, `--topics MAP.yaml` maps them")


def _from_log(path: Path, fmt: str, robot: RobotSpec, tmap: TopicMap, rate_hz: float,
              rep: IngestReport, progress) -> pd.DataFrame | None:
    by_topic = tmap.by_topic()
    wanted, mismatched = _wanted_for(tmap)
    res = _read_log(path, fmt, tmap, wanted, progress)
    _report_read(path, res, tmap, mismatched, rep)
    # time origin: first decoded message of a mapped topic
    joined: dict[str, Any] = {}
    firsts = []
    for topic in list(res.parts):
        parts = res.parts.pop(topic)  # free the per-block parts as soon as they are joined
        if not parts:
            continue
        kind = res.kinds[topic]
        joined[topic] = cdr.concat_parts(kind, parts)
        del parts
        ts = [p["t_ns"] for p in (joined[topic] if isinstance(joined[topic], list) else [joined[topic]])]
        firsts.append(min(int(t.min()) for t in ts if len(t)))
    if not firsts:
        rep.errors.append(_no_message_error(path, tmap))
        return None
    t0 = min(firsts)
    signals: list[_Signal] = []
    for topic in list(joined):
        part = joined.pop(topic)
        src = by_topic[topic]
        if src.kind == "joint_state":
            fixed = []
            for p in part:
                ps, _ = _sorted_part(p, topic, rep, t0)
                fixed.append(ps)
            _count_nonfinite(rep, topic, path, [p[f] for p in fixed for f in ("position", "velocity", "effort")
                                                if np.isfinite(p[f]).any()])
            signals += _joint_signals(src, fixed, t0, robot, rate_hz, rep)
        else:
            ps, t_s = _sorted_part(part, topic, rep, t0)
            _count_nonfinite(rep, topic, path, [v for k, v in ps.items()
                                                if k not in ("t_ns", "orientation", "cov0") and isinstance(v, np.ndarray)])
            signals += _signals_for(src, ps, t_s, robot, tmap, rate_hz)
        d = rep.topics[topic]
        if d.get("out_of_order") or d.get("duplicates"):
            rep.warnings.append(f"{path}: topic {topic}: {d['out_of_order']} out-of-order and "
                                f"{d['duplicates']} duplicate timestamp(s) (sorted, duplicates dropped)")
    t_end = max(float(s.t_s[-1]) for s in signals if len(s.t_s)) if signals else 0.0
    grid = np.arange(int(math.floor(t_end * rate_hz + 1e-6)) + 1) / rate_hz
    return _assemble(signals, grid, robot, rep)


def _count_nonfinite(rep: IngestReport, topic: str, path: Path, arrays: list[np.ndarray]) -> None:
    if not arrays:
        return
    n = len(arrays[0])
    bad = np.zeros(n, bool)
    for a in arrays:
        a2 = a.reshape(len(a), -1)
        if len(a2) == n:
            bad |= ~np.isfinite(a2).all(axis=1)
    k = int(bad.sum())
    if k:
        rep.topics[topic]["non_finite"] = rep.topics[topic].get("non_finite", 0) + k
        rep.warnings.append(f"{path}: topic {topic}: {k} message(s) with NaN/Inf fields (ticks marked invalid)")


# ----------------------------------------------------------------------------- tables (CSV/Parquet)
def _from_tabular(path: Path, fmt: str, robot: RobotSpec, tmap: TopicMap | None, rate_hz: float,
                  rep: IngestReport) -> pd.DataFrame | None:
    try:
        if fmt == "csv":
            df = pd.read_csv(path)
        else:
            import pyarrow.parquet as pq

            df = pq.read_table(path).to_pandas()
    except Exception as exc:  # noqa: BLE001 - parser errors of several types
        rep.errors.append(f"{path}: not a readable {fmt.upper()} file ({exc})")
        return None
    table_opts = tmap.table if tmap is not None else {}
    if table_opts.get("columns"):
        df = df.rename(columns=dict(table_opts["columns"]))
    tcol = table_opts.get("time_column", "t_s")
    if tcol not in df.columns:
        rep.errors.append(f"{path}: missing time column '{tcol}' (give a topic map with time_column "
                          "and columns to map your file's names)")
        return None
    t = pd.to_numeric(df[tcol], errors="coerce").to_numpy(float) * float(table_opts.get("time_scale", 1.0))
    fin = np.isfinite(t)
    if (~fin).any():
        rep.warnings.append(f"{path}: column '{tcol}': {int((~fin).sum())} row(s) without a finite time dropped")
    df, t = df[fin].reset_index(drop=True), t[fin]
    order, ooo, dup = clean_times(t)
    rep.topics["<table>"] = {"type": fmt, "mapped": True, "read": len(t), "decoded": len(order), "corrupt": 0,
                             "skipped": int((~fin).sum()), "out_of_order": ooo, "duplicates": dup, "non_finite": 0}
    if ooo or dup:
        rep.warnings.append(f"{path}: column '{tcol}': {ooo} out-of-order and {dup} duplicate time(s) "
                            "(sorted, duplicates dropped)")
    df, t = df.iloc[order].reset_index(drop=True), t[order]
    if len(t) == 0:
        rep.errors.append(f"{path}: no rows")
        return None
    t_s = t - t[0]
    spec = column_map(robot.n_wheels)
    if "run_id" in df.columns and df["run_id"].nunique() == 1:
        rep.topics["<table>"]["run_id"] = str(df["run_id"].iloc[0])
    signals = []
    for col in df.columns:
        if col not in spec or col in ("t_s", "run_id") or spec[col].group == "validity":
            continue
        vals = df[col]
        if col.startswith("gt_state"):
            codes = {**topics.WHEEL_STATE_CODES}
            v = vals.map(lambda s: codes.get(str(s), np.nan)).to_numpy(float)
        else:
            v = pd.to_numeric(vals, errors="coerce").to_numpy(float)
        if col == "terrain":
            v = np.where(v < 0, np.nan, v)
        g = spec[col].group
        if f"{g}_valid" in df.columns and g in VALID_GROUPS:
            v = np.where(df[f"{g}_valid"].astype(bool).to_numpy(), v, np.nan)
        ok = np.isfinite(v)
        method = "previous" if col.endswith(_PREVIOUS_COLUMNS) or col == "cam_confidence" else \
            ("angle" if col.endswith("yaw_rad") else "linear")
        ts = t_s[ok]
        gap = np.inf if col == "terrain" or col.startswith("gt_state") else gap_threshold_s(ts, rate_hz)
        signals.append(_Signal(col, ts, v[ok], method, gap))
    missing = [c.name for c in spec.values() if c.required and c.name not in df.columns]
    if missing:
        rep.warnings.append(f"{path}: column(s) {', '.join(missing)} missing (group marked invalid)")
    if not signals:
        rep.errors.append(f"{path}: no canonical column found (give a topic map with 'columns')")
        return None
    grid = np.arange(int(math.floor(t_s[-1] * rate_hz + 1e-6)) + 1) / rate_hz
    return _assemble(signals, grid, robot, rep)


# ----------------------------------------------------------------------------- public API
def load_run(path: str | Path, *, robot: RobotSpec | str | Path | None = None,
             topic_map: TopicMap | str | Path | dict | None = None, rate_hz: float = DEFAULT_RATE_HZ,
             progress: Callable[[int, int], None] | None = None) -> IngestResult:
    """Ingest one log into the canonical run table.

    Parameters
    ----------
    path : ``.mcap`` (ROS 2, CDR), ``.bag`` (ROS 1), ``.csv`` or ``.parquet``.
    robot : RobotSpec, built-in name or YAML path (default: the reference robot).
    topic_map : TopicMap, built-in name (``default``, ``husky_robot_localization``), YAML path or dict.
    rate_hz : base rate of the output grid (Hz).
    progress : optional ``(done, total)`` callback.

    Returns
    -------
    IngestResult with ``table`` (n_ticks rows; ``t_s`` from the first message, ``run_id`` = file stem,
    ``terrain`` from ``/terrain/label`` if present, ``gt_*`` from ``/sim/*``) and ``report``.
    """
    path = Path(path)
    rep = IngestReport(source=str(path), rate_hz=float(rate_hz))
    path, robot_spec, ok = _open_input(path, robot, rate_hz, rep)
    if not ok:
        return IngestResult(_empty_table(robot_spec), rep)
    fmt = rep.format
    try:
        if fmt in ("mcap", "bag"):
            tmap = load_topic_map(topic_map if topic_map is not None else
                                  ("default" if fmt == "mcap" else None))
            df = _from_log(path, fmt, robot_spec, tmap, float(rate_hz), rep, progress)
        else:
            tmap = load_topic_map(topic_map) if topic_map is not None else None
            df = _from_tabular(path, fmt, robot_spec, tmap, float(rate_hz), rep)
    except (LogReadError, TopicMapError) as exc:
        rep.errors.append(str(exc))
        return IngestResult(_empty_table(robot_spec), rep)
    if df is None or len(df) < 2:
        if df is not None:
            rep.errors.append(f"{path}: fewer than two ticks of data")
        return IngestResult(_empty_table(robot_spec), rep)
    run_id = rep.topics.get("<table>", {}).get("run_id", path.stem)
    df["run_id"] = run_id
    try:
        df = validate_run_table(df, robot_spec.n_wheels, source=str(path))
    except SchemaError as exc:
        rep.errors.append(str(exc))
        return IngestResult(_empty_table(robot_spec), rep)
    rep.rows = len(df)
    rep.span_s = float(df["t_s"].iloc[-1])
    rep.valid_fraction = {g: float(df[f"{g}_valid"].mean()) for g in VALID_GROUPS if f"{g}_valid" in df}
    rep.usable = any(rep.valid_fraction.get(g, 0.0) > 0 for g in ("wheels", "imu", "cam"))
    if not rep.usable:
        rep.errors.append(f"{path}: no valid wheel, IMU or camera sample on the base grid")
    df.attrs["terrainml"] = _run_metadata(path, robot_spec, tmap, rate_hz, rep, run_id)
    return IngestResult(df, rep)


def _open_input(path: Path, robot, rate_hz: float, rep: IngestReport) -> tuple[Path, RobotSpec, bool]:
    """Robot spec, rate check, ROS 2 bag folder and format sniffing (``rep.format``); errors go to
    ``rep.errors`` and give ``ok=False``."""
    try:
        robot_spec = load_robot(robot)
    except RobotSpecError as exc:
        rep.errors.append(str(exc))
        return path, load_robot(None), False
    if not (isinstance(rate_hz, (int, float)) and math.isfinite(rate_hz) and rate_hz > 0):
        rep.errors.append(f"rate_hz must be a positive number, got {rate_hz!r}")
        return path, robot_spec, False
    if path.is_dir():  # a ROS 2 bag folder (metadata.yaml + one .mcap): read its .mcap
        inner = sorted(path.glob("*.mcap"))
        if len(inner) == 1:
            path = inner[0]
    try:
        fmt = sniff_format(path) if path.is_file() else None
        if fmt is None:
            raise LogReadError(f"{path}: file not found" if not path.exists() else
                               f"{path}: not a file (a ROS 2 bag folder must hold exactly one .mcap)")
    except LogReadError as exc:
        rep.errors.append(str(exc))
        return path, robot_spec, False
    rep.format = fmt
    return path, robot_spec, True


def _run_metadata(path: Path, robot_spec: RobotSpec, tmap: TopicMap | None, rate_hz: float,
                  rep: IngestReport, run_id: str) -> dict[str, Any]:
    """SYSTEM §5 table metadata of an ingested log."""
    return make_metadata(
        robot_json=robot_spec.to_json(), source_file=str(path), source_sha256=_sha256(path),
        topic_map=tmap.to_dict() if tmap is not None else None, rate_hz=float(rate_hz),
        skipped=rep.skipped_per_topic(), corrupt=rep.corrupt_per_topic(), run_id=run_id,
        warnings=list(rep.warnings))


def write_run_mcap(table: pd.DataFrame, path: str | Path, robot: RobotSpec | str | None = None, *,
                   start_time_ns: int = 1_700_000_000_000_000_000) -> Path:
    """Write a canonical run table to a ROS 2 MCAP with the default topic map's messages.

    One message per row and sensor group where that group is valid (rows that are invalid are not
    written, so gaps survive the round trip). IMU vectors are rotated back to the IMU's own axes
    (inverse of the spec's mount rotation); camera rows are turned into T265 messages with
    :func:`terrainml.io.t265.body_to_t265_odometry` (robot pose integrated from the camera yaw and
    velocities); labels are written when they change and once a second.
    """
    from terrainml.io.mcap_writer import RosMcapWriter

    robot = load_robot(robot)
    n = robot.n_wheels
    df = validate_run_table(table, n)
    t = df["t_s"].to_numpy(float)
    rot_inv = Rotation.from_euler("xyz", [robot.imu.roll_rad, robot.imu.pitch_rad, robot.imu.yaw_rad]).inv()

    def col(name, default=np.nan):
        return df[name].to_numpy(float) if name in df else np.full(len(df), default)

    def valid(g):
        return df[f"{g}_valid"].to_numpy(bool) if f"{g}_valid" in df else np.zeros(len(df), bool)

    acc = rot_inv.apply(np.column_stack([col("imu_ax_mps2"), col("imu_ay_mps2"), col("imu_az_mps2")]))
    gyr = rot_inv.apply(np.column_stack([col("imu_roll_rate_radps", 0.0), col("imu_pitch_rate_radps", 0.0),
                                         col("imu_yaw_rate_radps")]))
    has_cam = "cam_vx_mps" in df and valid("cam").any() and robot.camera is not None
    if has_cam:
        mount = (robot.camera.x_m, robot.camera.y_m, robot.camera.z_m)
        yaw = np.nan_to_num(col("cam_yaw_rad"))
        vx, vy = t265.robot_velocity_from_mount(np.nan_to_num(col("cam_vx_mps")), np.nan_to_num(col("cam_vy_mps")),
                                                np.nan_to_num(col("cam_yaw_rate_radps")), mount[:2])
        dt = np.diff(t, prepend=t[0])
        xw = np.cumsum(dt * (vx * np.cos(yaw) - vy * np.sin(yaw)))
        yw = np.cumsum(dt * (vx * np.sin(yaw) + vy * np.cos(yaw)))
        msg = t265.body_to_t265_odometry(xw, yw, yaw, vx, vy, np.nan_to_num(col("cam_yaw_rate_radps")), mount)
        conf = col("cam_confidence", 3.0)
    wv, sv, cv, iv, camv, cmdv = (valid(g) for g in ("wheels", "steer", "current", "imu", "cam", "cmd"))
    omega = np.column_stack([col(f"wheel{i}_omega_radps") for i in range(1, n + 1)])
    steer = np.column_stack([col(f"wheel{i}_steer_rad", 0.0) for i in range(1, n + 1)])
    cur = np.column_stack([col(f"wheel{i}_current_a") for i in range(1, n + 1)])
    terrain = df["terrain"].to_numpy() if "terrain" in df else None
    has_gt = "gt_vx_mps" in df
    has_slip = f"gt_slip1" in df
    has_state = f"gt_state1" in df
    last_label, last_label_t = None, -1e9
    with RosMcapWriter(path, n, start_time_ns=start_time_ns) as w:
        for k in range(len(df)):
            tk = float(t[k])
            if iv[k]:
                w.write_imu(tk, acc[k], gyr[k])
            if has_cam and camv[k]:
                w.write_camera_odom(tk, msg["position_m"][k], msg["orientation_xyzw"][k], msg["linear_mps"][k],
                                    msg["angular_radps"][k], confidence=float(np.nan_to_num(conf[k], nan=3.0)))
            if wv[k] or sv[k]:
                w.write_wheel_joints(tk, omega[k] if wv[k] else np.full(n, np.nan),
                                     steer[k] if sv[k] else np.full(n, np.nan))
            if cv[k]:
                w.write_motor_current(tk, cur[k])
            if cmdv[k]:
                w.write_cmd_vel(tk, df["cmd_vx_mps"].iat[k], df["cmd_vy_mps"].iat[k], df["cmd_yaw_rate_radps"].iat[k])
            if terrain is not None and terrain[k] >= 0 and (terrain[k] != last_label or tk - last_label_t >= 1.0):
                w.write_terrain_label(tk, int(terrain[k]))
                last_label, last_label_t = terrain[k], tk
            if has_gt:
                w.write_ground_truth(tk, df["gt_x_m"].iat[k], df["gt_y_m"].iat[k], df["gt_yaw_rad"].iat[k],
                                     df["gt_vx_mps"].iat[k], df["gt_vy_mps"].iat[k], df["gt_yaw_rate_radps"].iat[k])
            if has_slip:
                w.write_wheel_slip(tk, [df[f"gt_slip{i}"].iat[k] for i in range(1, n + 1)], [0.0] * n, omega[k])
            if has_state:
                w.write_wheel_state(tk, [topics.WHEEL_STATE_CODES.get(str(df[f"gt_state{i}"].iat[k]), -1)
                                         for i in range(1, n + 1)])
    return Path(path)
