"""Finish a run (design §5): the one step every ingest path ends with.

A log (:mod:`terrainml.io.ingest.logs`), a table (:mod:`terrainml.io.ingest.tables`) and a dataset
run (:mod:`terrainml.io.ingest.dataset_runs`) each resample their sources onto the base grid;
:func:`finish_run` then sets ``run_id``, validates the table (contract 1), fills the report's rows,
span, valid fractions and ``usable`` and attaches the table metadata. :func:`failed` is the empty
result of a run that gave no table, the reason in the report.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any, Callable

import pandas as pd

from terrainml.hashing import sha256_file
from terrainml.io.ingest.ingest_report import IngestReport, IngestResult, Tally
from terrainml.io.topicmap import TopicMap
from terrainml.robot import RobotSpec, load_robot
from terrainml.schema import SchemaError, column_map, make_metadata, validate_run_table

__all__ = ["default_robot", "failed", "finish_run", "run_metadata"]


def default_robot(robot: RobotSpec | None, name: str | Path | None = None) -> RobotSpec:
    """``robot``; when None, the spec ``name`` (a dataset spec's ``robot``), else the reference robot.

    The one place ingest loads a robot spec: every ingest function below the public entry points
    takes the :class:`~terrainml.robot.RobotSpec` this gives."""
    return robot if robot is not None else load_robot(name)


def empty_table(robot: RobotSpec) -> pd.DataFrame:
    """A valid run table with the robot's required columns and no rows."""
    cols = {c.name: pd.Series([], dtype="float64") for c in column_map(robot.n_wheels).values() if c.required}
    return validate_run_table(pd.DataFrame(cols), robot.n_wheels)


def failed(rep: IngestReport, robot: RobotSpec, error: str | None) -> IngestResult:
    """The empty result of a run that could not be read, ``error`` (if any) added to the report."""
    if error is not None:
        rep.errors.append(error)
    return IngestResult(empty_table(robot), rep)


def _sha256(path: Path) -> str:
    """sha256 of a file; of a bag folder, of its files' names and hashes (sorted)."""
    if not path.is_dir():
        return sha256_file(path)
    return hashlib.sha256("".join(f"{p.name}:{sha256_file(p)}\n" for p in sorted(path.iterdir())
                                  if p.is_file()).encode()).hexdigest()


def run_metadata(path: Path, robot: RobotSpec, tmap: TopicMap | None, rate_hz: float,
                 rep: IngestReport, run_id: str) -> dict[str, Any]:
    """Design §5 table metadata of an ingested run (``path``: its log, table or primary file)."""
    return make_metadata(
        robot_json=robot.to_json(), source_file=str(path), source_sha256=_sha256(path),
        topic_map=tmap.to_dict() if tmap is not None else None, rate_hz=float(rate_hz),
        skipped=rep.skipped_per_topic(), corrupt=rep.corrupt_per_topic(), run_id=run_id,
        warnings=list(rep.warnings), damage=rep.damage())


def finish_run(df: pd.DataFrame | None, rep: IngestReport, robot: RobotSpec, source: Path, run_id: str, *,
               tmap: TopicMap | None, rate_hz: float, meta: dict[str, Any] | None = None,
               complete: Callable[[pd.DataFrame], str | None] | None = None) -> IngestResult:
    """The resampled table of one run -> the validated run table, its report filled in.

    Parameters
    ----------
    df : the resampled table (n_ticks rows, ``t_s`` from 0), or None when the reader already put
        the reason in ``rep.errors``.
    rep : the run's report; gets ``rows``, ``span_s``, ``valid_fraction`` and ``usable``.
    robot : the spec the table was read with (its wheel count is validated).
    source : the file named in errors and in the metadata (``source_file``, ``source_sha256``).
    run_id : the table's ``run_id``.
    tmap, rate_hz : topic map (None for tables) and base rate, recorded in the metadata.
    meta : entries added to the metadata (a dataset run's spec, classes and files).
    complete : a last step on the table before it is validated (a dataset run's absent columns
        and label); returns an error message to refuse the run, else None.

    Returns
    -------
    IngestResult: the table with its metadata in ``attrs["terrainml"]``, or an empty table when
    the run gave fewer than two ticks or failed validation (the reason in ``rep.errors``).
    """
    if df is None or len(df) < 2:   # None: the reader already reported why
        return failed(rep, robot, None if df is None else f"{source}: fewer than two ticks of data")
    if complete is not None:
        error = complete(df)
        if error is not None:
            return failed(rep, robot, error)
    df["run_id"] = run_id
    try:
        df = validate_run_table(df, robot.n_wheels, source=str(source))
    except SchemaError as exc:
        return failed(rep, robot, str(exc))
    tally = Tally()
    tally.add(df)
    tally.finish(rep, source)
    md = run_metadata(source, robot, tmap, rate_hz, rep, run_id)
    md.update(meta or {})
    df.attrs["terrainml"] = md
    return IngestResult(df, rep)
