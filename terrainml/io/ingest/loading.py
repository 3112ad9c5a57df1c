"""Log ingest: ROS 2 MCAP, ROS 1 bag, CSV or Parquet -> canonical run table (design §5, contract 1).

``load_run(path, robot=None, topic_map=None, rate_hz=100.0) -> IngestResult``: ``.table`` (validated
canonical DataFrame, metadata in ``attrs["terrainml"]``; zero rows when nothing usable was found) and
``.report`` (per-topic counts, warnings, ``usable``). ``ingest_to_parquet(LOG, OUT)`` (``terrainml
ingest LOG --out RUN.parquet``) writes the same table ``chunk_s`` seconds at a time, one row group
per chunk, with peak memory that does not grow with the log. Both run the log path of the engine
(:mod:`terrainml.io.ingest.logs`) into a sink (:mod:`terrainml.io.ingest.table_sinks`: DataFrame or
Parquet); CSV/Parquet inputs are tables already and are resampled in memory
(:mod:`terrainml.io.ingest.tables`); with ``dataset=``, one run of a multi-file dataset
(:mod:`terrainml.io.ingest.dataset_runs`). Every path ends in
:func:`terrainml.io.ingest.finish.finish_run`.

Never raises on bad input: damage is counted per topic (and, for tables, per column and cell
kind: :mod:`terrainml.io.ingest.cells`) and reported; the report's ``errors`` say why a file gave no
usable table. The counts travel with the table (metadata ``damage``; read them with
:func:`terrainml.io.damage.damage_summary`). A robot spec whose wheel count differs from the log's
is refused (:func:`terrainml.robot.check_wheel_count`).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Callable

import numpy as np
import pyarrow.parquet as pq

from terrainml.io.ingest.dataset_runs import load_dataset_file
from terrainml.io.ingest.dataset_spec import DatasetSpec
from terrainml.io.ingest.finish import default_robot, failed, finish_run, run_metadata
from terrainml.io.ingest.logs import FileLog, MemoryLog, produce, scan_log
from terrainml.io.ingest.ingest_report import IngestReport, IngestResult
from terrainml.io.ingest.table_sinks import FrameSink, ParquetSink
from terrainml.io.ingest.tables import Binding, TableFile, tables_to_run
from terrainml.io.readers import LogReadError, sniff_format
from terrainml.io.topicmap import TopicMap, TopicMapError, load_topic_map
from terrainml.robot import RobotSpec, RobotSpecError
from terrainml.schema import DEFAULT_RATE_HZ, METADATA_KEY, SchemaError, write_run_parquet

__all__ = ["load_run", "ingest_to_parquet"]

DEFAULT_CHUNK_S = 30.0
LOG_FORMATS = ("mcap", "bag", "rosbag2")


def _topic_map(topic_map, fmt: str) -> TopicMap | None:
    """The topic map of a log (default map for MCAP) or of a table (None: canonical names)."""
    if fmt in LOG_FORMATS:
        return load_topic_map(topic_map if topic_map is not None else ("default" if fmt == "mcap" else None))
    return load_topic_map(topic_map) if topic_map is not None else None


def _from_tabular(path: Path, fmt: str, robot: RobotSpec, tmap: TopicMap | None, rate_hz: float,
                  rep: IngestReport):
    """A CSV/Parquet run table (canonical names, or a topic map's ``columns`` renames) resampled
    onto the base grid by the tabular path (:mod:`terrainml.io.ingest.tables`)."""
    opts = tmap.table if tmap is not None else {}
    bindings = {canon: Binding(src) for src, canon in dict(opts.get("columns") or {}).items()}
    tf = TableFile(path, fmt, time_column=opts.get("time_column", "t_s"),
                   time_scale=float(opts.get("time_scale", 1.0)), bindings=bindings)
    return tables_to_run([tf], robot, rate_hz, rep)


def _kept_metadata(path: Path, fmt: str) -> dict:
    """What a Parquet run table's terrainml metadata says that the ingested table keeps: its class
    names (``classes``: the name of each ``terrain`` id, e.g. a run labelled by ``terrainml
    dataset label``). {} for any other file, or metadata that cannot be read."""
    if fmt != "parquet":
        return {}
    try:
        kv = pq.read_schema(path).metadata or {}
        classes = json.loads(kv[METADATA_KEY]).get("classes") if METADATA_KEY in kv else None
    except (OSError, ValueError, AttributeError):
        return {}
    return {"classes": [str(c) for c in classes]} if isinstance(classes, list) and classes else {}


def _open_input(path: Path, rate_hz: float, rep: IngestReport) -> tuple[Path, bool]:
    """Rate check, ROS 2 bag folder and format sniffing (``rep.format``); errors go to
    ``rep.errors`` and give ``ok=False``."""
    if not (isinstance(rate_hz, (int, float)) and math.isfinite(rate_hz) and rate_hz > 0):
        rep.errors.append(f"rate_hz must be a positive number, got {rate_hz!r}")
        return path, False
    if path.is_dir():  # a ROS 2 bag folder with one .mcap: our MCAP reader; else rosbags (.db3)
        inner = sorted(path.glob("*.mcap"))
        if len(inner) == 1:
            path = inner[0]
    try:
        if not path.exists():
            raise LogReadError(f"{path}: file not found")
        rep.format = sniff_format(path)
    except LogReadError as exc:
        rep.errors.append(str(exc))
        return path, False
    return path, True


# ----------------------------------------------------------------------------- public API
def load_run(path: str | Path, *, robot: RobotSpec | None = None,
             topic_map: TopicMap | str | Path | dict | None = None, rate_hz: float = DEFAULT_RATE_HZ,
             progress: Callable[[int, int], None] | None = None,
             dataset: DatasetSpec | str | Path | dict | None = None) -> IngestResult:
    """Ingest one log into the canonical run table.

    Parameters
    ----------
    path : ``.mcap`` (ROS 2, CDR), ``.bag`` (ROS 1), a ROS 2 bag folder, ``.csv`` or ``.parquet``;
        with ``dataset``, any file of one run of that dataset (e.g. BorealTC's ``pro_00.csv``).
    robot : the robot spec (:func:`terrainml.robot.load_robot` turns a name or YAML path into one);
        None: the dataset spec's robot, else the reference robot.
    topic_map : TopicMap, built-in name (``default``, ``husky_robot_localization``), YAML path or dict.
    rate_hz : base rate of the output grid (Hz).
    progress : optional ``(done, total)`` callback.
    dataset : a dataset spec (built-in name ``borealtc``, YAML path, dict): the run's files are
        found and paired by it (:mod:`terrainml.io.ingest.dataset_spec`).

    Returns
    -------
    IngestResult with ``table`` (n_ticks rows; ``t_s`` from the first message, ``run_id`` = file stem,
    ``terrain`` from ``/terrain/label`` if present, ``gt_*`` from ``/sim/*``; a Parquet run
    table's class names, ``attrs["terrainml"]["classes"]``, kept) and ``report``.
    """
    path = Path(path)
    if dataset is not None:
        return load_dataset_file(path, dataset, robot=robot, rate_hz=rate_hz)
    rep = IngestReport(source=str(path), rate_hz=float(rate_hz))
    robot = default_robot(robot)
    path, ok = _open_input(path, rate_hz, rep)
    if not ok:
        return failed(rep, robot, None)
    fmt = rep.format
    try:
        tmap = _topic_map(topic_map, fmt)
        if fmt in LOG_FORMATS:
            sink = FrameSink()
            log = MemoryLog(path, fmt, tmap, progress)
            p = scan_log(log, tmap, robot, float(rate_hz), rep)
            if p is not None:
                produce(log, p, tmap, robot, float(rate_hz), sink)
            df = sink.table()
        else:
            df = _from_tabular(path, fmt, robot, tmap, float(rate_hz), rep)
    except (LogReadError, TopicMapError, RobotSpecError) as exc:
        return failed(rep, robot, str(exc))
    run_id = rep.topics.get("<table>", {}).get("run_id", path.stem)
    return finish_run(df, rep, robot, path, run_id, tmap=tmap, rate_hz=rate_hz, meta=_kept_metadata(path, fmt))


def ingest_to_parquet(path: str | Path, out: str | Path, *, robot: RobotSpec | None = None,
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
    robot = default_robot(robot)
    path, ok = _open_input(path, rate_hz, rep)
    if not ok:
        return rep
    fmt = rep.format
    if fmt not in LOG_FORMATS:
        res = load_run(path, robot=robot, topic_map=topic_map, rate_hz=rate_hz, progress=progress)
        if res.report.usable:
            write_run_parquet(res.table, out)
        return res.report
    if not (isinstance(chunk_s, (int, float)) and np.isfinite(chunk_s) and chunk_s > 0):
        rep.errors.append(f"chunk_s must be a positive number, got {chunk_s!r}")
        return rep
    try:
        tmap = _topic_map(topic_map, fmt)
        log = FileLog(path, fmt, tmap, progress)
        p = scan_log(log, tmap, robot, float(rate_hz), rep)
        if p is None:
            return rep
        sink = ParquetSink(out, run_metadata(path, robot, tmap, rate_hz, rep, path.stem), path.stem,
                           robot.n_wheels)
        try:
            produce(log, p, tmap, robot, float(rate_hz), sink, max(int(round(chunk_s * rate_hz)), 1))
        except BaseException:
            sink.close(keep=False)
            raise
        sink.tally.finish(rep, path)
        sink.close(keep=rep.usable)
    except (LogReadError, TopicMapError, SchemaError, RobotSpecError) as exc:
        rep.errors.append(str(exc))
    return rep
