"""Window datasets from many logs (ingest -> estimate -> windows), through joblib or Dask.

:func:`build_dataset` runs :func:`process_log` on every log of a folder (sorted by path, so the
order is deterministic) with ``joblib.Parallel(n_jobs)``; given a Dask scheduler address the same
calls run on the cluster through ``joblib.parallel_config(backend="dask")`` (design §14).
Results are collected in input order, so a parallel or distributed build gives a table identical
to the sequential one.

On disk (``WINDOWS.parquet``) one row per window: ``run_id``, ``terrain`` (class id),
``t_start_s``, ``t_end_s``, ``start_index``, ``source`` and one fixed-size list column
``x__<channel>`` (T float64 samples) per channel. The Parquet key ``terrainml_windows`` holds
JSON: format/version, channels, window spec, robot spec, preset, class ids and names, per-rule
rejection counts, the per-run status table and the fingerprint.

The training-data fingerprint (:func:`fingerprint`) is the sha256 of the channel names, the
window length, every window's samples (float64, little-endian, C order), labels and run ids:
the same windows give the same fingerprint whatever file they were read from.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
from joblib import Parallel, delayed

from terrainml.atomic import atomic_output
from terrainml.classes import TERRAIN_CLASSES
from terrainml.estimation.run import estimate_run
from terrainml.features.chunks import chunk_source, cut_chunked_runs, needs_estimation
from terrainml.features.window_presets import DEFAULT_WINDOWS
from terrainml.features.windows import (RULES, SENSOR_GROUPS, Windows, WindowSpec, channel_column,
                                        channel_sensor_group, cut_windows, window_spec)
from terrainml.io.damage import damage_summary
from terrainml.io.ingest import load_dataset, load_run
from terrainml.schema import DEFAULT_RATE_HZ
from terrainml.robot import REFERENCE_ROBOT, RobotSpec, load_robot

__all__ = ["find_logs", "ingest_logs", "process_log", "build_dataset", "build_from_tables", "Dataset", "RunResult",
           "write_windows", "read_windows", "fingerprint", "DatasetError", "LOG_SUFFIXES", "SENSOR_GROUPS",
           "sensors_of", "class_report", "LOSS_HINT_FRACTION", "DEFAULT_WINDOWS", "FORMAT_ROBOTS",
           "dataset_robot", "resolve_spec", "run_class"]

FORMAT = "terrainml.windows"
FORMAT_VERSION = 1
META_KEY = b"terrainml_windows"
LOG_SUFFIXES = (".mcap", ".bag", ".parquet", ".csv")
NOT_LOGS = {"index.csv"}
#: dataset formats (``dataset build --format``) and the robot each is read with when none is named
FORMAT_ROBOTS = {"auto": REFERENCE_ROBOT, "borealtc": "husky"}
#: a class that keeps less than this share of its candidate windows gets a hint
LOSS_HINT_FRACTION = 0.5
#: what to try when a rule rejects most of a class (``dataset build`` prints it)
RULE_HINTS = {
    "time_gap": "its logs have gaps (see `terrainml inspect`); shorter windows (--windows chunks) fit between them",
    "wheel_state": "the robot rarely cruises on it; try --windows state (any moving wheel state) or "
                   "--windows chunks (fixed windows, no motion rule)",
    "speed": "the robot moves slowly or stands there; try --windows chunks (no motion rule)",
    "acceleration": "the robot keeps accelerating or braking there; try --windows state or --windows chunks",
    "steering": "the robot steers a lot there; try --windows chunks (no steering rule)",
    "terrain_label": "labels change inside windows (or are missing); shorter windows: --windows chunks",
    "channel_valid": "a sensor group is missing or invalid in its runs; train on the groups they have, "
                     "e.g. --sensors wheels,currents",
}


def sensors_of(channels) -> list[str]:
    """Sensor groups the channels need (wheels always: the estimator and the speeds need them)."""
    groups = {channel_sensor_group(c) for c in channels} - {"estimator"}
    return [g for g in SENSOR_GROUPS if g in groups or g == "wheels"]


class DatasetError(ValueError):
    """A dataset cannot be built or read (the message names the file)."""


@dataclass
class Dataset:
    """Windows plus how they were made.

    Attributes
    ----------
    windows : Windows (X (n, C, T), meta with run_id/terrain/...).
    runs : DataFrame, one row per log: ``source, run_id, status, message, n_rows, n_windows,
        n_kept`` and one column per rule of RULES.
    counts : dict, totals of ``n_windows, n_kept, n_rejected``, per rule, ``unlabelled``.
    robot : RobotSpec. spec : WindowSpec. preset : str.
    class_ids, class_names : the classes present (ids sorted) and their names.
    """

    windows: Windows
    runs: pd.DataFrame
    counts: dict
    robot: RobotSpec
    spec: WindowSpec
    preset: str = "robust"
    class_ids: list = field(default_factory=list)
    class_names: list = field(default_factory=list)
    class_report: pd.DataFrame | None = None

    @property
    def fingerprint(self) -> str:
        return fingerprint(self.windows)

    @property
    def sensors(self) -> list[str]:
        """Sensor groups the windows' channels need (see :func:`sensors_of`)."""
        return sensors_of(self.windows.channels)


def fingerprint(windows: Windows) -> str:
    """sha256 of channels, T, samples, labels and run ids (independent of the file format)."""
    h = hashlib.sha256()
    h.update(json.dumps(list(windows.channels)).encode())
    h.update(str(windows.X.shape[1:]).encode())
    h.update(np.ascontiguousarray(windows.X, dtype="<f8").tobytes())
    h.update(np.ascontiguousarray(windows.y, dtype="<i8").tobytes())
    h.update("\0".join(map(str, windows.groups)).encode())
    return h.hexdigest()


def find_logs(path: str | Path) -> list[Path]:
    """Logs in a folder, sorted: ``*.mcap`` (or ``*.bag``, else ``*.parquet``, else ``*.csv``).

    The first suffix present wins, so a simulator folder's ``index.csv`` and a dataset's
    Parquet outputs are not mistaken for logs. A file path gives itself.
    """
    path = Path(path)
    if path.is_file():
        return [path]
    if not path.is_dir():
        raise DatasetError(f"{path}: no such file or folder")
    for suf in LOG_SUFFIXES:
        found = sorted(p for p in path.rglob(f"*{suf}") if p.is_file() and p.name not in NOT_LOGS)
        if found:
            return found
    raise DatasetError(f"{path}: no logs (*.mcap, *.bag, *.parquet, *.csv) found")


@dataclass
class RunResult:
    """What one log gave the dataset (one row of :attr:`Dataset.runs`, and its windows).

    Attributes
    ----------
    source : file name of the log. run_id : the run's id (the table's ``run_id``, else the stem).
    status : ``ok``; ``damaged`` (usable, but the log lost messages or cells, counted in
        ``message``); ``unusable``; ``error``.
    message : why, for a status other than ``ok``. n_rows : rows of the run table.
    windows : Windows (unlabelled windows dropped), None until cut or when the run failed.
    counts : per rule of :data:`RULES` plus ``n_windows, n_kept, n_rejected, unlabelled``.
    class_names : the class names the table's metadata brings (None: ours).
    run_class : the run's most common label (-1 unlabelled): its rejections count under it.
    table : chunked specs only: the columns the windows are cut from once every run is read
        (:func:`terrainml.features.chunks.cut_chunked_runs`); None after cutting.
    """

    source: str
    run_id: str
    status: str = "ok"
    message: str = ""
    n_rows: int = 0
    windows: Windows | None = None
    counts: dict = field(default_factory=dict)
    class_names: list[str] | None = None
    run_class: int = -1
    table: pd.DataFrame | None = None

    def row(self) -> dict[str, Any]:
        """The run's row of :attr:`Dataset.runs` (missing counts are 0)."""
        c = self.counts
        row = {"source": self.source, "run_id": self.run_id, "status": self.status, "message": self.message,
               "n_rows": self.n_rows, "run_class": int(self.run_class), "n_windows": c.get("n_windows", 0),
               "n_kept": len(self.windows) if self.windows is not None else 0}
        row.update({k: c.get(k, 0) for k in ("n_rejected",) + RULES + ("unlabelled",)})
        return row


def process_log(path: str | Path, robot: RobotSpec, spec: WindowSpec, preset: str = "robust",
                table: pd.DataFrame | None = None) -> RunResult:
    """Ingest, estimate and window one log (or an already ingested run ``table``).

    ``spec`` is resolved (:meth:`WindowSpec.resolve`). A chunked spec's windows are cut later,
    over all runs (:func:`_collect`); the result then holds the run's columns in ``table``.
    One bad log never stops a build: its error is the result's ``status`` and ``message``.
    """
    path = Path(path)
    res = RunResult(source=path.name, run_id=path.stem)
    try:
        if table is None:
            table, why = _ingest_one(path, robot, spec.rate_hz)
            if table is None:
                res.status, res.message = "unusable", why
                return res
        _describe_run(table, res)
        channels = spec.channels_for(robot)
        if spec.chunk_s is not None:  # fixed chunks: cut over the whole dataset (class balancing)
            src = estimate_run(table, robot, preset) if needs_estimation(channels) else table
            res.table = chunk_source(src, table, robot, channels)
            return res
        res.windows, res.counts = _cut_run(table, robot, spec, preset, channels, res.run_id)
        res.windows.meta["source"] = path.name
    except Exception as exc:  # noqa: BLE001 - one bad log must not stop a fleet's build
        res.status, res.message = "error", f"{type(exc).__name__}: {exc}"
    return res


def ingest_logs(paths: Sequence[str | Path], robot: RobotSpec, n_jobs: int = 1,
                progress: Callable[[int, int, str], None] | None = None) -> tuple[list[pd.DataFrame], list[str]]:
    """The ingested run tables of logs (:func:`terrainml.io.ingest.load_run`), in path order.

    Parameters
    ----------
    paths : the logs (e.g. :func:`find_logs` of a folder).
    robot : RobotSpec they are read with.
    n_jobs : joblib jobs over the logs (-1: every core); the tables are the same for any value.
    progress : callback ``(done, total, log name)`` after each log, in path order.

    Returns
    -------
    (tables of the usable logs, ``"NAME: why"`` of every log left out): a log that cannot be
    read, or holds no usable row, is named with its ingest errors and never stops the others.
    """
    paths = [Path(p) for p in paths]
    tables, bad = [], []
    calls = (delayed(_ingest_one)(p, robot) for p in paths)
    for k, (p, (table, why)) in enumerate(zip(paths, Parallel(n_jobs=n_jobs, return_as="generator")(calls))):
        if table is None:
            bad.append(f"{p.name}: {why}")
        else:
            tables.append(table)
        if progress is not None:
            progress(k + 1, len(paths), p.name)
    return tables, bad


def _ingest_one(path: Path, robot: RobotSpec, rate_hz: float = DEFAULT_RATE_HZ) -> tuple[pd.DataFrame | None, str]:
    """(the run table, "") of a usable log, else (None, why not: its ingest errors)."""
    res = load_run(path, robot=robot, rate_hz=rate_hz)
    if res.report.usable and len(res.table):
        return res.table, ""
    return None, "; ".join(res.report.errors) or "no usable rows"


def _describe_run(table: pd.DataFrame, res: RunResult) -> None:
    """Fill what the run table says about itself: class names, run id, rows, damage, class."""
    meta = table.attrs.get("terrainml", {}) if hasattr(table, "attrs") else {}
    if isinstance(meta, dict) and meta.get("classes"):
        res.class_names = [str(c) for c in meta["classes"]]
    if "run_id" in table.columns and len(table):
        res.run_id = str(table["run_id"].iloc[0])
    res.n_rows = int(len(table))
    damage = damage_summary(table)
    if damage.any:  # usable, but what the log lost is said per run, not only at ingest
        res.status, res.message = "damaged", damage.text.removeprefix("damaged: ")
    res.run_class = run_class(table)


def _cut_run(table: pd.DataFrame, robot: RobotSpec, spec: WindowSpec, preset: str, channels,
             run_id: str) -> tuple[Windows, dict]:
    """Estimate one run and cut its labelled windows (counts include ``unlabelled``)."""
    est = estimate_run(table, robot, preset)
    for ch in channels:  # raw columns the estimator does not pass through (gyro roll/pitch)
        col = channel_column(ch, robot)[0]
        if col not in est.columns and col in table.columns and len(est) == len(table):
            est[col] = table[col].to_numpy()
    wins, counts = cut_windows(est, robot, spec, online=False, run_id=run_id)
    labelled = wins.meta["terrain"].to_numpy() >= 0
    counts["unlabelled"] = int((~labelled).sum())
    if not labelled.all():
        wins = wins.subset(np.flatnonzero(labelled))
    return wins, counts


def run_class(table: pd.DataFrame) -> int:
    """The run's most common label (-1 when unlabelled): the class its rejections are counted under."""
    if "terrain" not in table.columns or not len(table):
        return -1
    lab = pd.to_numeric(table["terrain"], errors="coerce")
    lab = lab[lab >= 0]
    return int(lab.mode().iloc[0]) if len(lab) else -1


def _cut_chunked(results: list[RunResult], robot: RobotSpec, spec: WindowSpec) -> None:
    """Cut the chunked spec's windows over every run that holds its columns; fill windows and counts."""
    ok = [r for r in results if r.table is not None and len(r.table)]
    if not ok:
        return
    cut = cut_chunked_runs([r.table for r in ok], [r.run_id for r in ok], robot, spec)
    for r, (w, counts) in zip(ok, cut):
        w.meta["source"] = r.source
        r.windows, r.counts, r.table = w, counts, None


def class_report(runs: pd.DataFrame, wins: Windows, names: Sequence[str] | None) -> pd.DataFrame:
    """Per class: runs, candidate windows (chunks for ``chunks``), kept windows, per-rule rejections.

    A run's rejections count under its most common label. ``hint`` says what to try when a
    class keeps less than :data:`LOSS_HINT_FRACTION` of its candidates (chunks: of its chunks).
    """
    rows: list[dict] = []
    if not len(runs) or "run_class" not in runs.columns:
        return pd.DataFrame(rows)
    kept_by_class = pd.Series(wins.y).value_counts().to_dict() if len(wins) else {}
    for cid, g in runs[runs["run_class"] >= 0].groupby("run_class"):
        cid = int(cid)
        name = names[cid] if names is not None and 0 <= cid < len(names) else str(cid)
        cand = int(g["n_windows"].sum())
        rej = {rule: int(g[rule].sum()) for rule in RULES if rule in g.columns}
        row = {"class_id": cid, "class": name, "runs": int(len(g)), "candidates": cand,
               "kept": int(kept_by_class.get(cid, 0)), **rej}
        # candidates that passed every rule (chunks: chunks kept; their windows are then balanced)
        share = (cand - int(g["n_rejected"].sum())) / cand if cand and "n_rejected" in g.columns else 0.0
        row["kept_share"] = round(share, 4)
        row["hint"] = ""
        if share < LOSS_HINT_FRACTION:
            worst = max(rej, key=rej.get) if rej and max(rej.values()) > 0 else None
            row["hint"] = f"keeps {share:.0%} of its candidates" + (
                f", most rejected by '{worst}': {RULE_HINTS[worst]}" if worst else "; check its runs' status")
        rows.append(row)
    return pd.DataFrame(rows)


def _collect(results: Sequence[RunResult], robot: RobotSpec, spec: WindowSpec, preset: str) -> Dataset:
    """The Dataset of the runs' results (in input order): windows, runs table, totals, classes."""
    results = list(results)
    _cut_chunked(results, robot, spec)
    rows = [r.row() for r in results]
    totals = {"n_windows": 0, "n_kept": 0, "n_rejected": 0, **{r: 0 for r in RULES}, "unlabelled": 0}
    for r in results:
        for k in totals:
            totals[k] += int(r.counts.get(k, 0))
    totals["n_kept"] = sum(row["n_kept"] for row in rows)
    names = next((r.class_names for r in reversed(results) if r.class_names), None)
    runs = pd.DataFrame(rows)
    wins = Windows.concat([r.windows for r in results if r.windows is not None],
                          channels=spec.channels_for(robot), n_samples=spec.n_samples, rate_hz=spec.rate_hz)
    ids = sorted(set(wins.y.tolist()))
    if names is not None:
        class_names = [names[i] if 0 <= i < len(names) else str(i) for i in ids]
        all_names = list(names)
    else:
        class_names = [TERRAIN_CLASSES[i] if 0 <= i < len(TERRAIN_CLASSES) else str(i) for i in ids]
        all_names = None
    ds = Dataset(wins, runs, totals, robot, spec, preset, ids, class_names,
                 class_report(runs, wins, all_names if all_names is not None else list(TERRAIN_CLASSES)))
    ds.windows.attrs["all_class_names"] = all_names
    return ds


def dataset_robot(robot: str | Path | RobotSpec | None = None, fmt: str = "auto") -> RobotSpec:
    """The robot of a dataset: ``robot`` resolved (name, YAML path or spec), else the format's.

    A folder of logs (``auto``) defaults to the reference robot, a BorealTC folder to the Husky
    it was recorded with (:data:`FORMAT_ROBOTS`). DatasetError names an unknown format;
    RobotSpecError an unknown robot.
    """
    if fmt not in FORMAT_ROBOTS:
        raise DatasetError(f"unknown --format {fmt!r}; expected {' or '.join(FORMAT_ROBOTS)}")
    return load_robot(robot if robot is not None else FORMAT_ROBOTS[fmt])


def resolve_spec(spec: WindowSpec | None, robot: RobotSpec, sensors: Sequence[str] | None = None) -> WindowSpec:
    """The window spec a dataset is built with: ``spec`` (default :data:`DEFAULT_WINDOWS`) resolved
    for ``robot`` and the sensor groups (:meth:`WindowSpec.resolve`); DatasetError names a bad group."""
    try:
        return (spec or window_spec(DEFAULT_WINDOWS)).resolve(robot, sensors)
    except ValueError as exc:
        raise DatasetError(str(exc)) from None


def build_dataset(source: str | Path | Sequence[str | Path], robot: RobotSpec | str | None = None,
                  preset: str = "robust", spec: WindowSpec | None = None, n_jobs: int = 1,
                  dask_address: str | None = None,
                  progress: Callable[[int, int, str], None] | None = None, *,
                  sensors: Sequence[str] | None = None, fmt: str = "auto",
                  say: Callable[[str], None] | None = None) -> Dataset:
    """Build the window dataset of a folder of logs (or a list of log paths, or a BorealTC folder).

    Parameters
    ----------
    source : folder (see :func:`find_logs`) or list of log paths; with ``fmt="borealtc"`` a
        BorealTC folder (``<CLASS>/pro_XX.csv``, read by :func:`terrainml.io.ingest.load_dataset`).
    robot : RobotSpec, name or path (default: the format's robot, :func:`dataset_robot`).
    preset : estimation preset (``robust`` or ``thesis``).
    spec : WindowSpec (default :data:`DEFAULT_WINDOWS`), resolved here with ``sensors``
        (:func:`resolve_spec`).
    n_jobs : joblib jobs (-1: all cores). Ignored scheduling-wise with ``dask_address``.
    dask_address : ``tcp://HOST:PORT`` of a Dask scheduler: run the logs on that cluster.
    progress : callback ``(done, total, source_name)`` after each log, in input order.
    sensors : sensor groups to keep (None: every group the channels have).
    fmt : ``auto`` (logs) or ``borealtc``.
    say : callback with one line about what a BorealTC folder held (runs, classes, skipped).

    Returns
    -------
    Dataset (windows in input-log order, per-run table, rejection counts).
    """
    robot = dataset_robot(robot, fmt)
    spec = resolve_spec(spec, robot, sensors)
    if fmt == "borealtc":
        return _build_borealtc(Path(source), robot, preset, spec, n_jobs, say)
    paths = find_logs(source) if isinstance(source, (str, Path)) else [Path(p) for p in source]
    total = len(paths)
    calls = (delayed(process_log)(p, robot, spec, preset) for p in paths)
    results = []

    def _consume(gen):
        for k, r in enumerate(gen):
            results.append(r)
            if progress is not None:
                progress(k + 1, total, r.source)

    if dask_address:
        from terrainml.pipeline.cluster import dask_jobs  # noqa: PLC0415 - dask, optional

        with dask_jobs(dask_address):
            _consume(Parallel(n_jobs=-1, return_as="generator")(calls))
    else:
        _consume(Parallel(n_jobs=n_jobs, return_as="generator")(calls))
    return _collect(results, robot, spec, preset)


def _build_borealtc(source: Path, robot: RobotSpec, preset: str, spec: WindowSpec, n_jobs: int,
                    say: Callable[[str], None] | None) -> Dataset:
    """The dataset of a BorealTC folder (DatasetError when no run could be read)."""
    return _from_tables(borealtc_tables(source, robot, say), robot, preset, spec, n_jobs)


def borealtc_tables(source: Path, robot: RobotSpec, say: Callable[[str], None] | None = None) -> list[pd.DataFrame]:
    """The ingested run tables of a BorealTC folder, with a one-line summary to ``say``.

    Raises DatasetError when no run could be read.
    """
    tables, rep = load_dataset("borealtc", source, robot=robot)
    if say is not None:
        say(f"BorealTC: {rep.runs} runs, classes {rep.classes}; runs without IMU (wheel channels "
            f"invalid, their windows rejected): {len(rep.runs_without('imu'))}; skipped: {len(rep.skipped)}")
    if not tables:
        raise DatasetError(f"{source}: no BorealTC runs read ({rep.skipped})")
    return tables


def build_from_tables(tables: Sequence[pd.DataFrame], robot: RobotSpec | str | None = None,
                      preset: str = "robust", spec: WindowSpec | None = None, n_jobs: int = 1,
                      names: Sequence[str] | None = None, *, sensors: Sequence[str] | None = None) -> Dataset:
    """Like :func:`build_dataset` for already ingested run tables (e.g. the BorealTC reader)."""
    robot = dataset_robot(robot)
    return _from_tables(tables, robot, preset, resolve_spec(spec, robot, sensors), n_jobs, names)


def _from_tables(tables: Sequence[pd.DataFrame], robot: RobotSpec, preset: str, spec: WindowSpec,
                 n_jobs: int, names: Sequence[str] | None = None) -> Dataset:
    names = names or [str(t["run_id"].iloc[0]) if "run_id" in t.columns and len(t) else f"run{k}"
                      for k, t in enumerate(tables)]
    results = Parallel(n_jobs=n_jobs)(delayed(process_log)(Path(n), robot, spec, preset, t)
                                      for n, t in zip(names, tables))
    return _collect(results, robot, spec, preset)


# ------------------------------------------------------------------------------ parquet
def write_windows(ds: Dataset, path: str | Path) -> Path:
    """Write a Dataset to ``path`` (Parquet, see the module docstring)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    w = ds.windows
    n, C, T = w.X.shape
    cols = {
        "run_id": pa.array([str(g) for g in w.meta["run_id"]], pa.string()),
        "terrain": pa.array(w.meta["terrain"].to_numpy(dtype=np.int64), pa.int64()),
        "t_start_s": pa.array(w.meta["t_start_s"].to_numpy(dtype=float), pa.float64()),
        "t_end_s": pa.array(w.meta["t_end_s"].to_numpy(dtype=float), pa.float64()),
        "start_index": pa.array(w.meta["start_index"].to_numpy(dtype=np.int64), pa.int64()),
        "source": pa.array([str(s) for s in w.meta.get("source", pd.Series([""] * n))], pa.string()),
    }
    for k, ch in enumerate(w.channels):
        flat = pa.array(np.ascontiguousarray(w.X[:, k, :]).reshape(-1), pa.float64())
        cols[f"x__{ch}"] = pa.FixedSizeListArray.from_arrays(flat, T)
    meta = {
        "format": FORMAT, "version": FORMAT_VERSION, "channels": list(w.channels), "n_samples": T,
        "rate_hz": w.rate_hz, "window_spec": ds.spec.to_dict(), "robot_spec": ds.robot.to_dict(),
        "robot_sha256": ds.robot.sha256(), "preset": ds.preset, "class_ids": ds.class_ids,
        "class_names": ds.class_names, "all_class_names": w.attrs.get("all_class_names"),
        "counts": ds.counts, "runs": json.loads(ds.runs.to_json(orient="records")),
        "class_report": ([] if ds.class_report is None else
                         json.loads(ds.class_report.to_json(orient="records"))),
        "fingerprint": fingerprint(w),
    }
    table = pa.table(cols).replace_schema_metadata({META_KEY: json.dumps(meta, sort_keys=True).encode()})
    with atomic_output(path) as tmp:   # whole or not at all; a failure names path
        pq.write_table(table, tmp, compression="zstd")
    return path


def read_windows(path: str | Path) -> Dataset:
    """Read a windows Parquet written by :func:`write_windows` (fingerprint verified)."""
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"{path}: no such windows file")
    try:
        table = pq.read_table(path)
    except Exception as exc:  # noqa: BLE001
        raise DatasetError(f"{path}: not a readable Parquet file ({exc})") from None
    raw = (table.schema.metadata or {}).get(META_KEY)
    if raw is None:
        raise DatasetError(f"{path}: not a terrainml windows file (no {META_KEY.decode()} metadata; "
                           "build one with `terrainml dataset build`)")
    meta = json.loads(raw)
    if meta.get("format") != FORMAT or meta.get("version") != FORMAT_VERSION:
        raise DatasetError(f"{path}: windows format {meta.get('format')!r} v{meta.get('version')!r} "
                           f"not readable (expected {FORMAT} v{FORMAT_VERSION})")
    channels = tuple(meta["channels"])
    T = int(meta["n_samples"])
    n = table.num_rows
    X = np.empty((n, len(channels), T))
    for k, ch in enumerate(channels):
        name = f"x__{ch}"
        if name not in table.column_names:
            raise DatasetError(f"{path}: column {name!r} missing")
        col = table.column(name).combine_chunks()
        X[:, k, :] = col.flatten().to_numpy(zero_copy_only=False).reshape(n, T)
    df = table.select(["run_id", "terrain", "t_start_s", "t_end_s", "start_index", "source"]).to_pandas()
    df["run_id"] = df["run_id"].astype(object)
    wins = Windows(X, channels, df, float(meta["rate_hz"]))
    wins.attrs["all_class_names"] = meta.get("all_class_names")
    if fingerprint(wins) != meta.get("fingerprint"):
        raise DatasetError(f"{path}: fingerprint mismatch: the windows were modified after writing")
    robot = RobotSpec.from_dict(meta["robot_spec"], source=f"{path}:robot")
    runs = pd.DataFrame(meta.get("runs", []))
    order = ["n_windows", "n_kept", "n_rejected", *RULES, "unlabelled"]
    raw_counts = meta.get("counts", {})
    counts = {k: raw_counts[k] for k in order if k in raw_counts}
    counts.update({k: v for k, v in raw_counts.items() if k not in counts})
    return Dataset(wins, runs, counts, robot, WindowSpec.from_dict(meta["window_spec"]),
                   meta.get("preset", "robust"), list(meta.get("class_ids", [])),
                   list(meta.get("class_names", [])), pd.DataFrame(meta.get("class_report", [])))
