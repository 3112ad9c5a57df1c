"""The BorealTC dataset (LaRocque et al., IROS 2024; CC0) through its built-in dataset spec.

Layout: ``<CLASS>/imu_XX.csv`` (about 100 Hz: ``time,wx,wy,wz,ax,ay,az`` in rad/s and m/s^2) and
``<CLASS>/pro_XX.csv`` (about 6.5 Hz: ``time,curL,curR,velL,velR`` in A and m/s); files with the
same ``XX`` are one run. Everything about the layout -- columns found by header name (other exports
order them differently), units, the Husky's side -> wheel mapping (left motor to wheels 1 and 3,
right to 2 and 4: ``wheel{i}_current_a`` is the *side* current, design §5 departure D4), classes
from the folder names -- is the spec ``terrainml/io/datasets/borealtc.yaml``, read by the one
ingest engine (:func:`terrainml.io.ingest.load_dataset_run`). This module only keeps the names
callers use. Runs whose IMU file is missing are returned with wheel channels only (``imu_valid``
False) and listed in the report.

``terrain`` holds the index into ``classes`` (the folder names, sorted) and the class names travel
in the table metadata.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from terrainml.io.dataset_spec import DatasetSpec, DatasetSpecError, RunFiles, load_dataset_spec
from terrainml.io.ingest import load_dataset_run
from terrainml.io.ingest_tables import read_table
from terrainml.robot import RobotSpec, load_robot
from terrainml.schema import DEFAULT_RATE_HZ

BorealTCError = DatasetSpecError   # a BorealTC folder or file cannot be read (the message names it)


@dataclass(frozen=True)
class BorealRun:
    run_id: str
    terrain: str
    pro_path: Path
    imu_path: Path | None
    files: RunFiles | None = None


@dataclass
class BorealReport:
    classes: list[str]
    runs: int = 0
    runs_without_imu: list[str] = field(default_factory=list)
    skipped: dict[str, str] = field(default_factory=dict)


def spec() -> DatasetSpec:
    return load_dataset_spec("borealtc")


def discover(root: str | Path) -> tuple[list[BorealRun], list[str]]:
    """Find runs under ``root``: every ``<CLASS>/pro_XX.csv`` with its ``imu_XX.csv`` if present."""
    sp = spec()
    runs = sp.discover(root)
    out = [BorealRun(r.run_id, r.fields["label"], r.files["pro"], r.files["imu"], r) for r in runs]
    return out, sp.label_names(runs)


def _read(path: str | Path, role: str) -> pd.DataFrame:
    """A BorealTC file by the spec's column names (header names and aliases), time-sorted."""
    sp = spec()
    f = next(x for x in sp.files if x.role == role)
    path = Path(path)
    wanted = [f.time_column] + [c.name for c in f.columns]
    aliases = {f.time_column: f.time_aliases, **{c.name: c.aliases for c in f.columns}}
    names = sp.resolve_columns(f, path, wanted, aliases)
    df, _ = read_table(path, "csv", list(names.values()))
    out = pd.DataFrame({k: pd.to_numeric(df[v], errors="coerce") for k, v in names.items()}).rename(
        columns={f.time_column: "time"})
    out = out[out["time"].notna()].sort_values("time", kind="stable")
    return out.drop_duplicates("time", keep="first").reset_index(drop=True)


def read_imu_csv(path: str | Path) -> pd.DataFrame:
    """IMU file -> DataFrame with time (s), wx, wy, wz (rad/s), ax, ay, az (m/s^2)."""
    return _read(path, "imu")


def read_pro_csv(path: str | Path) -> pd.DataFrame:
    """Proprioception file -> DataFrame with time (s), curL, curR (A), velL, velR (m/s)."""
    return _read(path, "pro")


def run_table(run: BorealRun, classes: list[str], robot: RobotSpec | None = None,
              rate_hz: float = DEFAULT_RATE_HZ) -> pd.DataFrame:
    """Canonical run table (design §5) of one BorealTC run at ``rate_hz``; raises BorealTCError."""
    robot = robot or load_robot("husky")
    if robot.n_wheels != 4:
        raise BorealTCError(f"robot spec '{robot.name}': BorealTC needs a four-wheel skid-steer spec")
    sp = spec()
    files = run.files or sp.run_of(run.pro_path)
    res = load_dataset_run(sp, files, robot=robot, rate_hz=rate_hz, label_names=list(classes))
    if not res.report.usable:
        raise BorealTCError("; ".join(res.report.errors) or f"{run.pro_path}: no usable run table")
    return res.table


def load_borealtc(root: str | Path, robot: RobotSpec | None = None, rate_hz: float = DEFAULT_RATE_HZ,
                  require_imu: bool = False) -> tuple[list[pd.DataFrame], BorealReport]:
    """Read every run of a BorealTC folder into canonical run tables.

    Parameters
    ----------
    require_imu : if True, runs without an IMU file are skipped (and counted); otherwise they are
        kept with wheel channels only.
    """
    runs, classes = discover(root)
    report = BorealReport(classes=classes)
    tables = []
    for run in runs:
        if run.imu_path is None:
            report.runs_without_imu.append(run.run_id)
            if require_imu:
                report.skipped[run.run_id] = "IMU file missing"
                continue
        try:
            tables.append(run_table(run, classes, robot, rate_hz))
        except BorealTCError as exc:
            report.skipped[run.run_id] = str(exc)
    report.runs = len(tables)
    return tables, report
