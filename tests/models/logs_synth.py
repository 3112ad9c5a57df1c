"""Tiny labelled logs for the models tests: canonical run tables written as Parquet.

Each run is a straight drive at a constant speed over one "terrain" whose slip and motor current
grow with the class id, so the true class of every window is known by construction. The tables
go through the real ingest (Parquet reader) and the real EKF.
"""

from __future__ import annotations

from pathlib import Path

from terrainml.schema import write_run_parquet

from synthetic_runs import CLASS_CURRENT_A, CLASS_SLIP, make_run_table  # noqa: F401


def write_logs(folder: Path, runs_per_class: int = 2, seed: int = 0,
               classes=(0, 2, 6)) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    k = 0
    for c in classes:
        for r in range(runs_per_class):
            rid = f"c{c}_r{r}_s{seed}"
            write_run_parquet(make_run_table(c, rid, seed * 1000 + k), folder / f"{rid}.parquet")
            k += 1
    return folder


