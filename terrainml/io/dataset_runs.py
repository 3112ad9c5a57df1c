"""Every run of a dataset folder as a canonical run table, through its dataset spec (design §5).

``iter_dataset_runs(spec, root)`` yields ``(run_id, table)`` one run at a time (memory of one run),
every table with the same class ids (the label names are taken once for the whole dataset) and
the names in ``table.attrs["terrainml"]["classes"]``. A run that cannot be read is skipped and
reported through ``on_skip`` (its errors name the file and column); a dataset-level problem (no
folder, no runs, a label that is not among the spec's names) raises
:class:`~terrainml.io.dataset_spec.DatasetSpecError`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable, Iterator

import pandas as pd

from terrainml.io.dataset_spec import DatasetSpec, load_dataset_spec
from terrainml.io.ingest import load_dataset_run
from terrainml.robot import RobotSpec


def iter_dataset_runs(spec: DatasetSpec | str | Path | dict, root: str | Path, *,
                      robot: RobotSpec | str | Path | None = None, rate_hz: float | None = None,
                      on_skip: Callable[[str, list[str]], None] | None = None) -> Iterator[tuple[str, pd.DataFrame]]:
    """Yield ``(run_id, table)`` for every run of ``root`` that gives a usable table.

    Parameters
    ----------
    spec : a dataset spec (built-in name ``borealtc``, YAML path, dict or DatasetSpec).
    root : the dataset folder (the spec's patterns are relative to it).
    robot, rate_hz : default: the spec's (else the reference robot, 100 Hz).
    on_skip : ``(run_id, errors)`` for each run without a usable table.
    """
    sp = load_dataset_spec(spec)
    runs = sp.discover(root)
    names = sp.label_names(runs)
    for run in runs:
        res = load_dataset_run(sp, run, robot=robot, rate_hz=rate_hz, label_names=names)
        if res.report.usable:
            yield run.run_id, res.table
        elif on_skip is not None:
            on_skip(run.run_id, list(res.report.errors))
