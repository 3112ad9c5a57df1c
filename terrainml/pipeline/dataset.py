"""Window datasets from many logs (ingest -> estimate -> windows), through joblib or Dask.

:func:`build_dataset` runs :func:`process_log` on every log of a folder (sorted by path, so the
order is deterministic) with ``joblib.Parallel(n_jobs)``; given a Dask scheduler address the same
calls run on the cluster through ``joblib.parallel_config(backend="dask")`` (SYSTEM §14).
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
from joblib import Parallel, delayed, parallel_config

from terrainml.classes import TERRAIN_CLASSES
from terrainml.estimation.run import estimate_run
from terrainml.features.windows import RULES, Windows, WindowSpec, cut_windows, default_channels
from terrainml.io.ingest import load_run
from terrainml.robot import RobotSpec, load_robot

__all__ = ["find_logs", "process_log", "build_dataset", "Dataset", "write_windows",
           "read_windows", "fingerprint", "DatasetError", "LOG_SUFFIXES"]

FORMAT = "terrainml.windows"
FORMAT_VERSION = 1
META_KEY = b"terrainml_windows"
LOG_SUFFIXES = (".mcap", ".bag", ".parquet", ".csv")
NOT_LOGS = {"index.csv"}


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

    @property
    def fingerprint(self) -> str:
        return fingerprint(self.windows)


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


def process_log(path: str | Path, robot: RobotSpec | str | None = None, preset: str = "robust",
                spec: WindowSpec | None = None, table: pd.DataFrame | None = None) -> dict[str, Any]:
    """Ingest, estimate and window one log (or an already ingested run ``table``).

    Returns
    -------
    dict with ``source``, ``run_id``, ``status`` (``ok``, ``unusable``, ``error``), ``message``,
    ``n_rows``, ``windows`` (Windows; unlabelled windows dropped), ``counts`` (per rule, plus
    ``unlabelled``), ``class_names`` (from the table's metadata when it brings its own).
    """
    spec = spec or WindowSpec()
    robot = robot if isinstance(robot, RobotSpec) else load_robot(robot)
    path = Path(path)
    out: dict[str, Any] = {"source": path.name, "run_id": path.stem, "status": "ok", "message": "",
                           "n_rows": 0, "windows": None, "counts": {}, "class_names": None}
    try:
        if table is None:
            res = load_run(path, robot=robot, rate_hz=spec.rate_hz)
            if not res.report.usable or len(res.table) == 0:
                out["status"] = "unusable"
                out["message"] = "; ".join(res.report.errors) or "no usable rows"
                return out
            table = res.table
        meta = table.attrs.get("terrainml", {}) if hasattr(table, "attrs") else {}
        if isinstance(meta, dict) and meta.get("classes"):
            out["class_names"] = [str(c) for c in meta["classes"]]
        if "run_id" in table.columns and len(table):
            out["run_id"] = str(table["run_id"].iloc[0])
        out["n_rows"] = int(len(table))
        est = estimate_run(table, robot, preset)
        wins, counts = cut_windows(est, robot, spec, online=False, run_id=out["run_id"])
        labelled = wins.meta["terrain"].to_numpy() >= 0
        counts["unlabelled"] = int((~labelled).sum())
        if not labelled.all():
            wins = wins.subset(np.flatnonzero(labelled))
        wins.meta["source"] = path.name
        out["windows"], out["counts"] = wins, counts
    except Exception as exc:  # noqa: BLE001 - one bad log must not stop a fleet's build
        out["status"] = "error"
        out["message"] = f"{type(exc).__name__}: {exc}"
    return out


def _collect(results: Sequence[dict], robot: RobotSpec, spec: WindowSpec, preset: str) -> Dataset:
    channels = tuple(spec.channels) if spec.channels is not None else default_channels(robot)
    rows = []
    totals = {"n_windows": 0, "n_kept": 0, "n_rejected": 0, **{r: 0 for r in RULES}, "unlabelled": 0}
    names = None
    for r in results:
        c = r["counts"]
        row = {"source": r["source"], "run_id": r["run_id"], "status": r["status"],
               "message": r["message"], "n_rows": r["n_rows"],
               "n_windows": c.get("n_windows", 0), "n_kept": len(r["windows"]) if r["windows"] is not None else 0}
        row.update({k: c.get(k, 0) for k in RULES + ("unlabelled",)})
        rows.append(row)
        for k in totals:
            totals[k] += int(c.get(k, 0))
        if r.get("class_names"):
            names = r["class_names"]
    totals["n_kept"] = sum(row["n_kept"] for row in rows)
    runs = pd.DataFrame(rows)
    wins = Windows.concat([r["windows"] for r in results if r["windows"] is not None],
                          channels=channels, n_samples=spec.n_samples, rate_hz=spec.rate_hz)
    ids = sorted(set(wins.y.tolist()))
    if names is not None:
        class_names = [names[i] if 0 <= i < len(names) else str(i) for i in ids]
        all_names = list(names)
    else:
        class_names = [TERRAIN_CLASSES[i] if 0 <= i < len(TERRAIN_CLASSES) else str(i) for i in ids]
        all_names = None
    ds = Dataset(wins, runs, totals, robot, spec, preset, ids, class_names)
    ds.windows.attrs["all_class_names"] = all_names
    return ds


def build_dataset(source: str | Path | Sequence[str | Path], robot: RobotSpec | str | None = None,
                  preset: str = "robust", spec: WindowSpec | None = None, n_jobs: int = 1,
                  dask_address: str | None = None,
                  progress: Callable[[int, int, str], None] | None = None) -> Dataset:
    """Build the window dataset of a folder of logs (or a list of log paths).

    Parameters
    ----------
    source : folder (see :func:`find_logs`) or list of log paths.
    robot : RobotSpec, name or path (default the reference robot).
    preset : estimation preset (``robust`` or ``thesis``).
    spec : WindowSpec (default SYSTEM §8).
    n_jobs : joblib jobs (-1: all cores). Ignored scheduling-wise with ``dask_address``.
    dask_address : ``tcp://HOST:PORT`` of a Dask scheduler: run the logs on that cluster.
    progress : callback ``(done, total, source_name)`` after each log, in input order.

    Returns
    -------
    Dataset (windows in input-log order, per-run table, rejection counts).
    """
    spec = spec or WindowSpec()
    robot = robot if isinstance(robot, RobotSpec) else load_robot(robot)
    paths = find_logs(source) if isinstance(source, (str, Path)) else [Path(p) for p in source]
    total = len(paths)
    calls = (delayed(process_log)(p, robot, preset, spec) for p in paths)
    results = []

    def _consume(gen):
        for k, r in enumerate(gen):
            results.append(r)
            if progress is not None:
                progress(k + 1, total, r["source"])

    if dask_address:
        from distributed import Client  # noqa: PLC0415 - dask, optional

        with Client(dask_address, timeout="30s") as client:  # noqa: F841 - registers the backend
            with parallel_config(backend="dask"):
                _consume(Parallel(n_jobs=-1, return_as="generator")(calls))
    else:
        _consume(Parallel(n_jobs=n_jobs, return_as="generator")(calls))
    return _collect(results, robot, spec, preset)


def build_from_tables(tables: Sequence[pd.DataFrame], robot: RobotSpec | str | None = None,
                      preset: str = "robust", spec: WindowSpec | None = None, n_jobs: int = 1,
                      names: Sequence[str] | None = None) -> Dataset:
    """Like :func:`build_dataset` for already ingested run tables (e.g. the BorealTC reader)."""
    spec = spec or WindowSpec()
    robot = robot if isinstance(robot, RobotSpec) else load_robot(robot)
    names = names or [str(t["run_id"].iloc[0]) if "run_id" in t.columns and len(t) else f"run{k}"
                      for k, t in enumerate(tables)]
    results = Parallel(n_jobs=n_jobs)(delayed(process_log)(Path(n), robot, preset, spec, t)
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
        "fingerprint": fingerprint(w),
    }
    table = pa.table(cols).replace_schema_metadata({META_KEY: json.dumps(meta, sort_keys=True).encode()})
    pq.write_table(table, path, compression="zstd")
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
                   list(meta.get("class_names", [])))
