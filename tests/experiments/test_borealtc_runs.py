"""Run selection of the BorealTC experiments (fast tier: hand-made run tables)."""

import pandas as pd

from terrainml.experiments.borealtc import runs_with_imu


def _run(run_id: str, terrain: int, imu: bool) -> pd.DataFrame:
    return pd.DataFrame({"t_s": [0.0, 0.01], "terrain": terrain, "run_id": run_id, "imu_valid": imu})


def test_runs_with_imu_takes_the_first_runs_of_every_class_that_have_an_imu_file():
    tables = [_run("SNOW_01", 4, True), _run("ASPHALT_02", 0, True), _run("ASPHALT_00", 0, True),
              _run("ASPHALT_01", 0, False), _run("SNOW_00", 4, True), _run("ASPHALT_03", 0, True)]
    ids = [str(t["run_id"].iloc[0]) for t in runs_with_imu(tables, 2, exclude=["ASPHALT_00"])]
    assert ids == ["ASPHALT_02", "ASPHALT_03", "SNOW_00", "SNOW_01"]
    assert [str(t["run_id"].iloc[0]) for t in runs_with_imu(tables, 1)] == ["ASPHALT_00", "SNOW_00"]
