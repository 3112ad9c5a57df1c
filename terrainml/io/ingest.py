"""Log ingest: ROS 2 MCAP, ROS 1 bag, CSV or Parquet -> canonical run table (design §5, contract 1).

``load_run(path, robot=None, topic_map=None, rate_hz=100.0) -> IngestResult``: ``.table`` (validated
canonical DataFrame, metadata in ``attrs["terrainml"]``; zero rows when nothing usable was found) and
``.report`` (per-topic counts, warnings, ``usable``). ``ingest_to_parquet(LOG, OUT)`` (``terrainml
ingest LOG --out RUN.parquet``) writes the same table ``chunk_s`` seconds at a time, one row group
per chunk, with peak memory that does not grow with the log. Both run the engine of
:mod:`terrainml.io.ingest_engine` into a sink (DataFrame or Parquet); CSV/Parquet inputs are
tables already and are resampled in memory.

Never raises on bad input: damage is counted per topic (and, for tables, per column and cell
kind: :mod:`terrainml.io.cells`) and reported; the report's ``errors`` say why a file gave no usable
table. The counts travel with the table (metadata ``damage``; read them with
:func:`terrainml.io.damage.damage_summary`). A robot spec whose wheel count differs from the log's
is refused (:func:`terrainml.robot.check_wheel_count`). ``write_run_mcap`` writes a run table back to a ROS 2 MCAP with
the default topic map's messages, so a hand-made table round-trips.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
from scipy.spatial.transform import Rotation

from terrainml.hashing import sha256_file
from terrainml.io import t265, topics
from terrainml.io.damage import damage_metadata
from terrainml.io.dataset_spec import DatasetSpec, DatasetSpecError, RunFiles, load_dataset_spec
from terrainml.io.ingest_engine import FileLog, IngestReport, MemoryLog, produce, scan_log
from terrainml.io.ingest_tables import Binding, TableFile, tables_to_run
from terrainml.io.mcap_writer import RosMcapWriter
from terrainml.io.readers import LogReadError, sniff_format
from terrainml.io.topicmap import TopicMap, TopicMapError, load_topic_map
from terrainml.robot import RobotSpec, RobotSpecError, load_robot
from terrainml.schema import (DEFAULT_RATE_HZ, METADATA_KEY, VALID_GROUPS, SchemaError, column_map,
                              make_metadata, valid_column, validate_run_table, wheel_col,
                              write_run_parquet)

__all__ = ["IngestReport", "IngestResult", "load_run", "load_dataset_run", "ingest_to_parquet", "write_run_mcap"]

DEFAULT_CHUNK_S = 30.0
LOG_FORMATS = ("mcap", "bag", "rosbag2")


@dataclass
class IngestResult:
    table: pd.DataFrame
    report: IngestReport


# ----------------------------------------------------------------------------- sinks
@dataclass
class _Tally:
    """Row count, last tick and valid ticks per group of the chunks a sink took."""

    rows: int = 0
    last_t_s: float = 0.0
    valid: dict[str, int] = field(default_factory=lambda: {g: 0 for g in VALID_GROUPS})

    def add(self, df: pd.DataFrame) -> None:
        self.rows += len(df)
        self.last_t_s = float(df["t_s"].iloc[-1])
        for g in VALID_GROUPS:
            if valid_column(g).name in df:
                self.valid[g] += int(df[valid_column(g).name].sum())

    def finish(self, rep: IngestReport, path: Path) -> None:
        """Rows, span, valid fractions and ``usable`` into the report."""
        rep.rows, rep.span_s = self.rows, self.last_t_s
        rep.valid_fraction = {g: v / self.rows for g, v in self.valid.items()} if self.rows else {}
        rep.usable = self.rows >= 2 and any(rep.valid_fraction.get(g, 0.0) > 0 for g in ("wheels", "imu", "cam"))
        if not rep.usable:
            rep.errors.append(f"{path}: no valid wheel, IMU or camera sample on the base grid")


@dataclass
class _FrameSink:
    """Chunks kept in memory and joined into one DataFrame (``load_run``)."""

    chunks: list[pd.DataFrame] = field(default_factory=list)

    def write(self, chunk: pd.DataFrame) -> None:
        self.chunks.append(chunk)

    def table(self) -> pd.DataFrame | None:
        if not self.chunks:
            return None
        return self.chunks[0] if len(self.chunks) == 1 else pd.concat(self.chunks, ignore_index=True)


@dataclass
class _ParquetSink:
    """Chunks appended to a Parquet file as row groups (``ingest_to_parquet``): written to a
    hidden ``.part`` file beside ``out``, moved over ``out`` only when the table is usable."""

    out: Path
    meta: dict[str, Any]
    run_id: str
    n_wheels: int
    tally: _Tally = field(default_factory=_Tally)
    writer: pq.ParquetWriter | None = None
    schema: pa.Schema | None = None

    @property
    def tmp(self) -> Path:
        return self.out.with_name(f".{self.out.name}.part")

    def write(self, chunk: pd.DataFrame) -> None:
        chunk["run_id"] = self.run_id
        if self.writer is None:  # every chunk has the same columns and dtypes: check the first,
            chunk = validate_run_table(chunk, self.n_wheels, source=self.meta["source_file"])  # the
            table = pa.Table.from_pandas(chunk, preserve_index=False)          # Parquet schema the rest
            kv = dict(table.schema.metadata or {})
            kv[METADATA_KEY] = json.dumps(self.meta, default=str).encode()
            self.schema = table.schema.with_metadata(kv)
            self.out.parent.mkdir(parents=True, exist_ok=True)
            self.writer = pq.ParquetWriter(self.tmp, self.schema)
        # columns straight to Arrow (pandas' converter is ~2x slower per chunk)
        text = (pa.types.is_string, pa.types.is_large_string)
        table = pa.Table.from_arrays([pa.array(chunk[f.name].to_numpy(dtype=object if any(k(f.type) for k in text)
                                                                      else None), type=f.type)
                                      for f in self.schema], schema=self.schema)
        self.writer.write_table(table)
        self.tally.add(chunk)

    def close(self, keep: bool) -> None:
        """Finish the file; move it to ``out`` when ``keep``, else leave nothing behind."""
        if self.writer is not None:
            self.writer.close()
        if keep:
            os.replace(self.tmp, self.out)
        else:
            self.tmp.unlink(missing_ok=True)


# ----------------------------------------------------------------------------- helpers
def _empty_table(robot: RobotSpec) -> pd.DataFrame:
    cols = {c.name: pd.Series([], dtype="float64") for c in column_map(robot.n_wheels).values() if c.required}
    return validate_run_table(pd.DataFrame(cols), robot.n_wheels)


def _failed(rep: IngestReport, robot: RobotSpec, error: str | None) -> IngestResult:
    """The empty result of a run that could not be read, ``error`` (if any) added to the report."""
    if error is not None:
        rep.errors.append(error)
    return IngestResult(_empty_table(robot), rep)


def _topic_map(topic_map, fmt: str) -> TopicMap | None:
    """The topic map of a log (default map for MCAP) or of a table (None: canonical names)."""
    if fmt in LOG_FORMATS:
        return load_topic_map(topic_map if topic_map is not None else ("default" if fmt == "mcap" else None))
    return load_topic_map(topic_map) if topic_map is not None else None


# ----------------------------------------------------------------------------- tables (CSV/Parquet)
def _from_tabular(path: Path, fmt: str, robot: RobotSpec, tmap: TopicMap | None, rate_hz: float,
                  rep: IngestReport) -> pd.DataFrame | None:
    """A CSV/Parquet run table (canonical names, or a topic map's ``columns`` renames) resampled
    onto the base grid by the tabular path (:mod:`terrainml.io.ingest_tables`)."""
    opts = tmap.table if tmap is not None else {}
    bindings = {canon: Binding(src) for src, canon in dict(opts.get("columns") or {}).items()}
    tf = TableFile(path, fmt, time_column=opts.get("time_column", "t_s"),
                   time_scale=float(opts.get("time_scale", 1.0)), bindings=bindings)
    return tables_to_run([tf], robot, rate_hz, rep)


# ----------------------------------------------------------------------------- public API
def load_run(path: str | Path, *, robot: RobotSpec | str | Path | None = None,
             topic_map: TopicMap | str | Path | dict | None = None, rate_hz: float = DEFAULT_RATE_HZ,
             progress: Callable[[int, int], None] | None = None,
             dataset: DatasetSpec | str | Path | dict | None = None) -> IngestResult:
    """Ingest one log into the canonical run table.

    Parameters
    ----------
    path : ``.mcap`` (ROS 2, CDR), ``.bag`` (ROS 1), a ROS 2 bag folder, ``.csv`` or ``.parquet``;
        with ``dataset``, any file of one run of that dataset (e.g. BorealTC's ``pro_00.csv``).
    robot : RobotSpec, built-in name or YAML path (default: the reference robot, or the dataset
        spec's robot).
    topic_map : TopicMap, built-in name (``default``, ``husky_robot_localization``), YAML path or dict.
    rate_hz : base rate of the output grid (Hz).
    progress : optional ``(done, total)`` callback.
    dataset : a dataset spec (built-in name ``borealtc``, YAML path, dict): the run's files are
        found and paired by it (:mod:`terrainml.io.dataset_spec`).

    Returns
    -------
    IngestResult with ``table`` (n_ticks rows; ``t_s`` from the first message, ``run_id`` = file stem,
    ``terrain`` from ``/terrain/label`` if present, ``gt_*`` from ``/sim/*``) and ``report``.
    """
    path = Path(path)
    if dataset is not None:
        return _load_dataset_file(path, dataset, robot, rate_hz)
    rep = IngestReport(source=str(path), rate_hz=float(rate_hz))
    path, robot_spec, ok = _open_input(path, robot, rate_hz, rep)
    if not ok:
        return IngestResult(_empty_table(robot_spec), rep)
    fmt = rep.format
    try:
        tmap = _topic_map(topic_map, fmt)
        if fmt in LOG_FORMATS:
            sink = _FrameSink()
            log = MemoryLog(path, fmt, tmap, progress)
            p = scan_log(log, tmap, robot_spec, float(rate_hz), rep)
            if p is not None:
                produce(log, p, tmap, robot_spec, float(rate_hz), sink)
            df = sink.table()
        else:
            df = _from_tabular(path, fmt, robot_spec, tmap, float(rate_hz), rep)
    except (LogReadError, TopicMapError, RobotSpecError) as exc:
        return _failed(rep, robot_spec, str(exc))
    if df is None or len(df) < 2:   # None: the reader already reported why
        return _failed(rep, robot_spec, None if df is None else f"{path}: fewer than two ticks of data")
    run_id = rep.topics.get("<table>", {}).get("run_id", path.stem)
    df["run_id"] = run_id
    try:
        df = validate_run_table(df, robot_spec.n_wheels, source=str(path))
    except SchemaError as exc:
        rep.errors.append(str(exc))
        return IngestResult(_empty_table(robot_spec), rep)
    tally = _Tally()
    tally.add(df)
    tally.finish(rep, path)
    df.attrs["terrainml"] = _run_metadata(path, robot_spec, tmap, rate_hz, rep, run_id)
    return IngestResult(df, rep)


def ingest_to_parquet(path: str | Path, out: str | Path, *, robot: RobotSpec | str | Path | None = None,
                      topic_map: TopicMap | str | Path | dict | None = None, rate_hz: float = DEFAULT_RATE_HZ,
                      chunk_s: float = DEFAULT_CHUNK_S,
                      progress: Callable[[int, int], None] | None = None,
                      dataset: DatasetSpec | str | Path | dict | None = None) -> IngestReport:
    """Ingest a log into a Parquet run table with memory bounded by ``chunk_s`` (not the log length).

    Parameters
    ----------
    path : ``.mcap`` (ROS 2) or ``.bag`` (ROS 1) streamed; ``.csv``/``.parquet`` via ``load_run``.
    out : output ``.parquet``; written only when a usable table resulted (else nothing is left).
    robot, topic_map, rate_hz, dataset : as :func:`load_run` (a dataset run goes through ``load_run``).
    chunk_s : seconds of base-rate ticks per chunk (one Parquet row group each).
    progress : optional ``(done, total)`` callback (two passes over the file's bytes).

    Returns
    -------
    IngestReport, as ``load_run(...).report`` (``rows``, ``span_s``, ``valid_fraction``,
    ``usable``, per-topic counts, warnings, errors). The file equals
    ``write_run_parquet(load_run(...).table, out)`` read back, within float rounding.
    """
    path, out = Path(path), Path(out)
    if dataset is not None:
        res = load_run(path, robot=robot, rate_hz=rate_hz, dataset=dataset)
        if res.report.usable:
            write_run_parquet(res.table, out)
        return res.report
    rep = IngestReport(source=str(path), rate_hz=float(rate_hz))
    path, robot_spec, ok = _open_input(path, robot, rate_hz, rep)
    if not ok:
        return rep
    fmt = rep.format
    if fmt not in LOG_FORMATS:
        res = load_run(path, robot=robot_spec, topic_map=topic_map, rate_hz=rate_hz, progress=progress)
        if res.report.usable:
            write_run_parquet(res.table, out)
        return res.report
    if not (isinstance(chunk_s, (int, float)) and np.isfinite(chunk_s) and chunk_s > 0):
        rep.errors.append(f"chunk_s must be a positive number, got {chunk_s!r}")
        return rep
    try:
        tmap = _topic_map(topic_map, fmt)
        log = FileLog(path, fmt, tmap, progress)
        p = scan_log(log, tmap, robot_spec, float(rate_hz), rep)
        if p is None:
            return rep
        sink = _ParquetSink(out, _run_metadata(path, robot_spec, tmap, rate_hz, rep, path.stem), path.stem,
                            robot_spec.n_wheels)
        try:
            produce(log, p, tmap, robot_spec, float(rate_hz), sink, max(int(round(chunk_s * rate_hz)), 1))
        except BaseException:
            sink.close(keep=False)
            raise
        sink.tally.finish(rep, path)
        sink.close(keep=rep.usable)
    except (LogReadError, TopicMapError, SchemaError, RobotSpecError) as exc:
        rep.errors.append(str(exc))
    return rep


def load_dataset_run(spec: DatasetSpec, run: RunFiles, *, robot: RobotSpec | str | Path | None = None,
                     rate_hz: float | None = None, label_names: list[str] | None = None) -> IngestResult:
    """One run of a dataset (its files paired by ``spec``) into the canonical run table.

    Parameters
    ----------
    spec, run : the dataset spec and one of its runs (:meth:`DatasetSpec.discover`, ``run_of``).
    robot : default: the spec's robot (else the reference robot).
    rate_hz : default: the spec's ``rate_hz`` (else 100 Hz).
    label_names : the class names (ids are their order); default ``spec.label_names([run])``
        (pass the whole dataset's, :func:`terrainml.io.dataset_runs.iter_dataset_runs`, so that
        every run has the same ids).

    Returns
    -------
    IngestResult: ``table`` with ``run_id`` from the spec's template, ``terrain`` (the run's label
    on every row for folder/file labels; per row, held until the next label and never across a
    hole, for column labels) and the class names in ``attrs["terrainml"]["classes"]``; errors
    (a missing column or file, an unknown label) in ``report.errors``, naming the file and column.
    """
    rate_hz = float(rate_hz if rate_hz is not None else spec.rate_hz or DEFAULT_RATE_HZ)
    rep = IngestReport(source=str(run.primary), rate_hz=rate_hz, format="dataset:" + spec.name)
    try:
        robot_spec = load_robot(robot if robot is not None else spec.robot)
    except RobotSpecError as exc:
        rep.errors.append(str(exc))
        return IngestResult(_empty_table(load_robot(None)), rep)
    try:
        names = label_names if label_names is not None else spec.label_names([run])
        label = spec.run_label(run)
        files = spec.table_files(run, robot_spec, names)
        df = tables_to_run(files, robot_spec, rate_hz, rep, span=spec.span if len(files) > 1 else "first",
                           missing_steer_ok=True)
    except (DatasetSpecError, RobotSpecError, SchemaError) as exc:
        return _failed(rep, robot_spec, str(exc))
    if df is None or len(df) < 2:   # None: the reader already reported why
        return _failed(rep, robot_spec, None if df is None else f"{run.primary}: fewer than two ticks of data")
    for col in spec.absent_columns(run, robot_spec):   # an optional file absent: its columns NaN
        if col not in df:
            df[col] = np.nan
    if label is not None:   # a run-level label (folder, label file): true on every row
        if names is None or label not in names:
            rep.errors.append(f"{run.primary}: label {label!r} is not one of the label names {names}")
            return IngestResult(_empty_table(robot_spec), rep)
        df["terrain"] = np.full(len(df), names.index(label), dtype=np.int64)
    df["run_id"] = run.run_id
    try:
        df = validate_run_table(df, robot_spec.n_wheels, source=str(run.primary))
    except SchemaError as exc:
        rep.errors.append(str(exc))
        return IngestResult(_empty_table(robot_spec), rep)
    tally = _Tally()
    tally.add(df)
    tally.finish(rep, run.primary)
    meta = _run_metadata(run.primary, robot_spec, None, rate_hz, rep, run.run_id)
    meta.update(dataset=spec.name, dataset_spec=spec.source_file, classes=names,
                files={role: None if p is None else str(p) for role, p in run.files.items()})
    df.attrs["terrainml"] = meta
    return IngestResult(df, rep)


def _load_dataset_file(path: Path, dataset, robot, rate_hz) -> IngestResult:
    """``load_run(path, dataset=...)``: the run ``path`` belongs to, by the spec's patterns."""
    rep = IngestReport(source=str(path), rate_hz=float(rate_hz))
    try:
        spec = load_dataset_spec(dataset)
        run = spec.run_of(path)
        # folder labels: the class list is the dataset's (every run gets the same ids)
        names = spec.label_names(spec.discover(run.root)) if spec.label.source == "folder" else None
    except DatasetSpecError as exc:
        rep.errors.append(str(exc))
        return IngestResult(_empty_table(load_robot(None)), rep)
    return load_dataset_run(spec, run, robot=robot, rate_hz=rate_hz, label_names=names)


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
    if path.is_dir():  # a ROS 2 bag folder with one .mcap: our MCAP reader; else rosbags (.db3)
        inner = sorted(path.glob("*.mcap"))
        if len(inner) == 1:
            path = inner[0]
    try:
        if not path.exists():
            raise LogReadError(f"{path}: file not found")
        fmt = sniff_format(path)
    except LogReadError as exc:
        rep.errors.append(str(exc))
        return path, robot_spec, False
    rep.format = fmt
    return path, robot_spec, True


def _sha256(path: Path) -> str:
    """sha256 of a file; of a bag folder, of its files' names and hashes (sorted)."""
    if not path.is_dir():
        return sha256_file(path)
    return hashlib.sha256("".join(f"{p.name}:{sha256_file(p)}\n" for p in sorted(path.iterdir())
                                  if p.is_file()).encode()).hexdigest()


def _run_metadata(path: Path, robot_spec: RobotSpec, tmap: TopicMap | None, rate_hz: float,
                  rep: IngestReport, run_id: str) -> dict[str, Any]:
    """Design §5 table metadata of an ingested log."""
    return make_metadata(
        robot_json=robot_spec.to_json(), source_file=str(path), source_sha256=_sha256(path),
        topic_map=tmap.to_dict() if tmap is not None else None, rate_hz=float(rate_hz),
        skipped=rep.skipped_per_topic(), corrupt=rep.corrupt_per_topic(), run_id=run_id,
        warnings=list(rep.warnings), damage=damage_metadata(rep))


def write_run_mcap(table: pd.DataFrame, path: str | Path, robot: RobotSpec | str | None = None, *,
                   start_time_ns: int = 1_700_000_000_000_000_000) -> Path:
    """Write a canonical run table to a ROS 2 MCAP with the default topic map's messages.

    One message per row and sensor group where that group is valid (rows that are invalid are not
    written, so gaps survive the round trip). IMU vectors are rotated back to the IMU's own axes
    (inverse of the spec's mount rotation); camera rows are turned into T265 messages with
    :func:`terrainml.io.t265.body_to_t265_odometry` (robot pose integrated from the camera yaw and
    velocities); labels are written when they change and once a second.
    """
    robot = load_robot(robot)
    n = robot.n_wheels
    df = validate_run_table(table, n)
    t = df["t_s"].to_numpy(float)
    rot_inv = Rotation.from_euler("xyz", [robot.imu.roll_rad, robot.imu.pitch_rad, robot.imu.yaw_rad]).inv()

    def col(name, default=np.nan):
        return df[name].to_numpy(float) if name in df else np.full(len(df), default)

    def valid(g):
        c = valid_column(g).name
        return df[c].to_numpy(bool) if c in df else np.zeros(len(df), bool)

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
    omega = np.column_stack([col(wheel_col("omega", i)) for i in range(1, n + 1)])
    steer = np.column_stack([col(wheel_col("steer", i), 0.0) for i in range(1, n + 1)])
    cur = np.column_stack([col(wheel_col("current", i)) for i in range(1, n + 1)])
    terrain = df["terrain"].to_numpy() if "terrain" in df else None
    has_gt = "gt_vx_mps" in df
    has_slip = "gt_slip1" in df
    has_state = "gt_state1" in df
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
