"""Runs of a multi-file CSV/Parquet dataset as canonical run tables, through its dataset spec (design §5).

:func:`load_dataset_run` reads one run (its files paired by the spec,
:mod:`terrainml.io.ingest.dataset_spec`) through the tabular path of the engine
(:mod:`terrainml.io.ingest.tables`); :func:`load_dataset` reads every run of a dataset folder,
every table with the same class ids (the label names are taken once for the whole dataset) and the
names in ``table.attrs["terrainml"]["classes"]``. A run that cannot be read is skipped and
reported (its errors name the file and column); a dataset-level problem (no folder, no runs, a
label that is not among the spec's names) raises
:class:`~terrainml.io.ingest.dataset_spec.DatasetSpecError`.

BorealTC (LaRocque et al., IROS 2024; CC0) is the built-in spec ``borealtc``
(``terrainml/io/datasets/borealtc.yaml``): ``<CLASS>/pro_XX.csv`` (about 6.5 Hz: side currents in A,
side speeds in m/s) and the optional ``<CLASS>/imu_XX.csv`` (about 100 Hz); the Husky's left motor
feeds wheels 1 and 3, the right 2 and 4 (``wheel{i}_current_a`` is the *side* current, design §5
departure D4); classes are the folder names, sorted. ``load_dataset("borealtc", folder)`` reads
them all; runs without their IMU file keep wheel channels only (``imu_valid`` False) and are
listed in the report (``runs_without("imu")``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from terrainml.io.ingest.dataset_spec import DatasetSpec, DatasetSpecError, RunFiles, load_dataset_spec
from terrainml.io.ingest.finish import default_robot, failed, finish_run
from terrainml.io.ingest.ingest_report import IngestReport, IngestResult
from terrainml.io.ingest.tables import tables_to_run
from terrainml.robot import RobotSpec, RobotSpecError
from terrainml.schema import DEFAULT_RATE_HZ, SchemaError

__all__ = ["DatasetReport", "load_dataset", "load_dataset_run", "load_dataset_file"]


def load_dataset_run(spec: DatasetSpec, run: RunFiles, *, robot: RobotSpec | None = None,
                     rate_hz: float | None = None, label_names: list[str] | None = None) -> IngestResult:
    """One run of a dataset (its files paired by ``spec``) into the canonical run table.

    Parameters
    ----------
    spec, run : the dataset spec and one of its runs (:meth:`DatasetSpec.discover`, ``run_of``).
    robot : default: the spec's robot (else the reference robot).
    rate_hz : default: the spec's ``rate_hz`` (else 100 Hz).
    label_names : the class names (ids are their order); default ``spec.label_names([run])``
        (pass the whole dataset's, as :func:`load_dataset` does, so that every run has the same ids).

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
        robot = default_robot(robot, spec.robot)
    except RobotSpecError as exc:
        return failed(rep, default_robot(None), str(exc))
    try:
        names = label_names if label_names is not None else spec.label_names([run])
        label = spec.run_label(run)
        files = spec.table_files(run, robot, names)
        df = tables_to_run(files, robot, rate_hz, rep, span=spec.span if len(files) > 1 else "first",
                           missing_steer_ok=True)
    except (DatasetSpecError, RobotSpecError, SchemaError) as exc:
        return failed(rep, robot, str(exc))

    def complete(df: pd.DataFrame) -> str | None:
        for col in spec.absent_columns(run, robot):   # an optional file absent: its columns NaN
            if col not in df:
                df[col] = np.nan
        if label is not None:   # a run-level label (folder, label file): true on every row
            if names is None or label not in names:
                return f"{run.primary}: label {label!r} is not one of the label names {names}"
            df["terrain"] = np.full(len(df), names.index(label), dtype=np.int64)
        return None

    meta = dict(dataset=spec.name, dataset_spec=spec.source_file, classes=names,
                files={role: None if p is None else str(p) for role, p in run.files.items()})
    return finish_run(df, rep, robot, run.primary, run.run_id, tmap=None, rate_hz=rate_hz, meta=meta,
                      complete=complete)


def load_dataset_file(path: Path, dataset: DatasetSpec | str | Path | dict, *, robot: RobotSpec | None = None,
                      rate_hz: float = DEFAULT_RATE_HZ) -> IngestResult:
    """``load_run(path, dataset=...)``: the run ``path`` belongs to, by the spec's patterns."""
    rep = IngestReport(source=str(path), rate_hz=float(rate_hz))
    try:
        spec = load_dataset_spec(dataset)
        run = spec.run_of(path)
        # folder labels: the class list is the dataset's (every run gets the same ids)
        names = spec.label_names(spec.discover(run.root)) if spec.label.source == "folder" else None
    except DatasetSpecError as exc:
        return failed(rep, default_robot(None), str(exc))
    return load_dataset_run(spec, run, robot=robot, rate_hz=rate_hz, label_names=names)


@dataclass
class DatasetReport:
    """What :func:`load_dataset` read: the class names (ids are their order), the runs read, the
    runs whose optional files are absent (role -> run ids) and the runs skipped (run id -> why)."""

    classes: list[str] | None
    runs: int = 0
    run_ids: list[str] = field(default_factory=list)
    absent: dict[str, list[str]] = field(default_factory=dict)
    skipped: dict[str, str] = field(default_factory=dict)

    def runs_without(self, role: str) -> list[str]:
        """The runs whose ``role`` file (an optional one, e.g. BorealTC's ``imu``) is absent."""
        return list(self.absent.get(role, []))


def load_dataset(spec: DatasetSpec | str | Path | dict, root: str | Path, *, robot: RobotSpec | None = None,
                 rate_hz: float | None = None,
                 require: tuple[str, ...] = ()) -> tuple[list[pd.DataFrame], DatasetReport]:
    """Every run of a dataset folder that gives a usable table, with the same class ids.

    Parameters
    ----------
    spec : a dataset spec (built-in name ``borealtc``, YAML path, dict or DatasetSpec).
    root : the dataset folder (the spec's patterns are relative to it).
    robot, rate_hz : default: the spec's (else the reference robot, 100 Hz).
    require : roles of optional files a run must have to be read (e.g. ``("imu",)``); a run
        without one is skipped and counted.

    Returns
    -------
    (tables, report): the run tables in the spec's run order (sorted by path) and a
    :class:`DatasetReport`.

    Raises
    ------
    DatasetSpecError : the folder, its runs or their labels cannot be used (the message names them).
    RobotSpecError : the spec's robot cannot be loaded (``robot`` None).
    """
    sp = load_dataset_spec(spec)
    robot = default_robot(robot, sp.robot)   # once for every run
    runs = sp.discover(root)
    report = DatasetReport(classes=sp.label_names(runs))
    tables = []
    for run in runs:
        absent = [role for role, p in run.files.items() if p is None]
        for role in absent:
            report.absent.setdefault(role, []).append(run.run_id)
        missing = [role for role in require if role in absent]
        if missing:
            report.skipped[run.run_id] = f"{', '.join(missing)} file missing"
            continue
        res = load_dataset_run(sp, run, robot=robot, rate_hz=rate_hz, label_names=report.classes)
        if res.report.usable:
            tables.append(res.table)
            report.run_ids.append(run.run_id)
        else:
            report.skipped[run.run_id] = "; ".join(res.report.errors) or f"{run.primary}: no usable run table"
    report.runs = len(tables)
    return tables, report
