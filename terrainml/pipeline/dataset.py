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
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
from joblib import Parallel, delayed, parallel_config

from terrainml.classes import TERRAIN_CLASSES
from terrainml.estimation.run import estimate_run
from terrainml.features.chunks import chunk_windows, make_chunks
from terrainml.features.windows import (RULES, SIDE_CHANNEL_NAMES, Windows, WindowSpec, channel_column,
                                        channel_sensor_group, cut_windows, default_channels, window_spec)
from terrainml.io.damage import damage_summary
from terrainml.io.ingest import load_run
from terrainml.robot import RobotSpec, load_robot

__all__ = ["find_logs", "process_log", "build_dataset", "Dataset", "write_windows",
           "read_windows", "fingerprint", "DatasetError", "LOG_SUFFIXES", "SENSOR_GROUPS",
           "dataset_channels", "sensors_of", "class_report", "LOSS_HINT_FRACTION", "DEFAULT_WINDOWS"]

#: window spec of a dataset built without one (design §8, issue #19): ``short`` windows exist in
#: stop-and-go and after every transition, so a model trained by default serves through them
#: (``steady`` 2 s windows rarely exist there); grouped CV on ``sim_default``: SVM 0.997 against
#: 0.990 with ``steady``
DEFAULT_WINDOWS = "short"

FORMAT = "terrainml.windows"
FORMAT_VERSION = 1
META_KEY = b"terrainml_windows"
LOG_SUFFIXES = (".mcap", ".bag", ".parquet", ".csv")
NOT_LOGS = {"index.csv"}
#: sensor groups a model may need (``train --sensors``): wheel speeds, motor currents, IMU, camera
SENSOR_GROUPS = ("wheels", "currents", "imu", "cam")
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


def dataset_channels(robot: RobotSpec, spec: WindowSpec, sensors=None) -> tuple[str, ...]:
    """Window channels for a robot and spec, restricted to the sensor groups ``sensors``.

    ``spec.channels`` wins when given. The ``chunks`` spec takes the side channels of a
    camera-less robot (design §8), the other specs the canonical channels
    (:func:`~terrainml.features.windows.default_channels`). ``sensors`` (None: all) drops the
    channels of the groups not listed; ValueError names an unknown group.
    """
    if sensors is not None:
        unknown = [g for g in sensors if g not in SENSOR_GROUPS]
        if unknown:
            raise ValueError(f"unknown sensor group(s) {unknown}; expected some of {list(SENSOR_GROUPS)}")
    if spec.channels is not None:
        chans = tuple(spec.channels)
    elif spec.chunk_s is not None:
        chans = SIDE_CHANNEL_NAMES
    else:
        chans = default_channels(robot)
    if sensors is None:
        return chans
    keep = set(sensors) | {"estimator", "wheels"}
    out = tuple(c for c in chans if channel_sensor_group(c) in keep)
    if not out:
        raise ValueError(f"no window channel left for sensors {list(sensors)} (channels {list(chans)})")
    return out


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


def process_log(path: str | Path, robot: RobotSpec, preset: str = "robust",
                spec: WindowSpec | None = None, table: pd.DataFrame | None = None) -> dict[str, Any]:
    """Ingest, estimate and window one log (or an already ingested run ``table``).

    Returns
    -------
    dict with ``source``, ``run_id``, ``status`` (``ok``; ``damaged``, usable but the log lost
    messages or cells, counted in ``message``; ``unusable``, ``error``), ``message``,
    ``n_rows``, ``windows`` (Windows; unlabelled windows dropped), ``counts`` (per rule, plus
    ``unlabelled``), ``class_names`` (from the table's metadata when it brings its own).
    """
    spec = spec or window_spec(DEFAULT_WINDOWS)
    path = Path(path)
    out: dict[str, Any] = {"source": path.name, "run_id": path.stem, "status": "ok", "message": "",
                           "n_rows": 0, "windows": None, "counts": {}, "class_names": None,
                           "run_class": -1, "table": None}
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
        damage = damage_summary(table)
        if damage.any:  # usable, but what the log lost is said per run, not only at ingest
            out["status"], out["message"] = "damaged", damage.text.removeprefix("damaged: ")
        out["run_class"] = _run_class(table)
        channels = spec.channels if spec.channels is not None else default_channels(robot)
        if spec.chunk_s is not None:
            # fixed chunks are cut over the whole dataset (the class balancing needs every run)
            out["table"] = _chunk_table(table, robot, channels, preset)
            return out
        est = estimate_run(table, robot, preset)
        for ch in channels:  # raw columns the estimator does not pass through (gyro roll/pitch)
            col = channel_column(ch, robot)[0]
            if col not in est.columns and col in table.columns and len(est) == len(table):
                est[col] = table[col].to_numpy()
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


def _run_class(table: pd.DataFrame) -> int:
    """The run's most common label (-1 when unlabelled): the class its rejections are counted under."""
    if "terrain" not in table.columns or not len(table):
        return -1
    lab = pd.to_numeric(table["terrain"], errors="coerce")
    lab = lab[lab >= 0]
    return int(lab.mode().iloc[0]) if len(lab) else -1


def _needs_estimation(channels) -> bool:
    return any(channel_sensor_group(c) in ("estimator", "cam") for c in channels)


def _chunk_table(table: pd.DataFrame, robot: RobotSpec, channels, preset: str) -> pd.DataFrame:
    """The columns the ``chunks`` spec needs (estimated first only when a channel needs the EKF)."""
    src = estimate_run(table, robot, preset) if _needs_estimation(channels) else table
    cols = ["t_s", "run_id", "terrain"]
    for ch in channels:
        col, vcols, _ = channel_column(ch, robot)
        cols += [col, *vcols]
    out = pd.DataFrame({c: src[c].to_numpy() for c in dict.fromkeys(cols) if c in src.columns})
    if "run_id" not in out.columns:
        out["run_id"] = str(table["run_id"].iloc[0]) if "run_id" in table.columns else ""
    if "terrain" not in out.columns:
        out["terrain"] = -1
    out.attrs["terrainml"] = {"rate_hz": (table.attrs.get("terrainml") or {}).get("rate_hz")}
    return out


def _chunk_results(results: list[dict], robot: RobotSpec, spec: WindowSpec, channels) -> None:
    """Cut the ``chunks`` spec's windows over all runs at once; fill each result's windows and counts."""
    ok = [r for r in results if r.get("table") is not None and len(r["table"])]
    if not ok:
        return
    valid_cols = sorted({v for ch in channels for v in channel_column(ch, robot)[1]})
    tables = [r["table"] for r in ok]
    chunks = make_chunks(tables, chunk_s=float(spec.chunk_s), valid_cols=valid_cols)
    cols = {ch: channel_column(ch, robot)[0] for ch in channels}
    T = spec.n_samples
    if len(chunks):
        wins = chunk_windows(tables, chunks, window_s=spec.window_s, max_windows_per_chunk=spec.windows_per_chunk,
                             homogeneous=spec.homogeneous, channels=cols, wheel_radius_m=robot.wheel_radius_m)
    else:
        wins = Windows.concat([], channels=channels, n_samples=T, rate_hz=spec.rate_hz)
    L = chunks.chunk_samples
    run_of_window = wins.meta["run_id"].astype(str).to_numpy() if len(wins) else np.array([], dtype=object)
    kept_chunks = chunks.meta.groupby("table").size().to_dict() if len(chunks) else {}
    for k, r in enumerate(ok):
        sel = np.flatnonzero(run_of_window == str(r["run_id"]))
        w = wins.subset(sel)
        w.meta = w.meta.drop(columns=["chunk_id"], errors="ignore")
        w.meta["source"] = r["source"]
        n_chunks = len(r["table"]) // L
        lost = n_chunks - int(kept_chunks.get(k, 0))
        counts = {"n_windows": int(n_chunks), "n_kept": int(len(w)), "n_rejected": int(lost)}
        counts.update({rule: 0 for rule in RULES})
        # a dropped chunk had an invalid sample or a missing or changing label
        invalid = _invalid_chunks(r["table"], L, valid_cols)
        counts["channel_valid"] = int(min(invalid, lost))
        counts["terrain_label"] = int(lost - min(invalid, lost))
        counts["unlabelled"] = 0
        r["windows"], r["counts"], r["table"] = w, counts, None


def _invalid_chunks(df: pd.DataFrame, L: int, valid_cols) -> int:
    ok = np.ones(len(df), bool)
    for c in valid_cols:
        if c in df.columns:
            ok &= df[c].to_numpy(dtype=bool)
    n = len(df) // L
    return int(sum(not ok[s * L:(s + 1) * L].all() for s in range(n)))


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


def _collect(results: Sequence[dict], robot: RobotSpec, spec: WindowSpec, preset: str) -> Dataset:
    channels = tuple(spec.channels) if spec.channels is not None else default_channels(robot)
    if spec.chunk_s is not None:
        _chunk_results(list(results), robot, spec, channels)
    rows = []
    totals = {"n_windows": 0, "n_kept": 0, "n_rejected": 0, **{r: 0 for r in RULES}, "unlabelled": 0}
    names = None
    for r in results:
        c = r["counts"]
        row = {"source": r["source"], "run_id": r["run_id"], "status": r["status"],
               "message": r["message"], "n_rows": r["n_rows"], "run_class": int(r.get("run_class", -1)),
               "n_windows": c.get("n_windows", 0), "n_kept": len(r["windows"]) if r["windows"] is not None else 0}
        row.update({k: c.get(k, 0) for k in ("n_rejected",) + RULES + ("unlabelled",)})
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
    ds = Dataset(wins, runs, totals, robot, spec, preset, ids, class_names,
                 class_report(runs, wins, all_names if all_names is not None else list(TERRAIN_CLASSES)))
    ds.windows.attrs["all_class_names"] = all_names
    return ds


def _with_channels(spec: WindowSpec, robot: RobotSpec) -> WindowSpec:
    """The ``chunks`` spec without channels gets the side channels (other specs keep None)."""
    if spec.chunk_s is not None and spec.channels is None:
        return replace(spec, channels=dataset_channels(robot, spec))
    return spec


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
    spec : WindowSpec (default design §8).
    n_jobs : joblib jobs (-1: all cores). Ignored scheduling-wise with ``dask_address``.
    dask_address : ``tcp://HOST:PORT`` of a Dask scheduler: run the logs on that cluster.
    progress : callback ``(done, total, source_name)`` after each log, in input order.

    Returns
    -------
    Dataset (windows in input-log order, per-run table, rejection counts).
    """
    spec = spec or window_spec(DEFAULT_WINDOWS)
    robot = load_robot(robot)
    spec = _with_channels(spec, robot)
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
    spec = spec or window_spec(DEFAULT_WINDOWS)
    robot = load_robot(robot)
    spec = _with_channels(spec, robot)
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
        "class_report": ([] if ds.class_report is None else
                         json.loads(ds.class_report.to_json(orient="records"))),
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
                   list(meta.get("class_names", [])), pd.DataFrame(meta.get("class_report", [])))
