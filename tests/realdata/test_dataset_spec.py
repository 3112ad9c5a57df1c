"""Another layout through a dataset spec, derived from the real BorealTC runs.

The derived dataset has reordered columns, wheel speeds in m/s under other names, separate wheel
and IMU files in one flat folder, times in ms, gyro rates in deg/s and the labels as strings in a
column. Through a user spec it must give the same canonical tables as the built-in path (values
converted back: the ground truth is the built-in table of the original files).
"""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from terrainml.io.ingest import load_dataset, load_dataset_run
from terrainml.io.ingest.dataset_spec import load_dataset_spec

BOREAL = Path(__file__).resolve().parents[2].parent / "shared" / "datasets" / "borealtc"

pytestmark = [pytest.mark.acceptance,
              pytest.mark.skipif(not BOREAL.is_dir(), reason=f"real dataset not present at {BOREAL}")]
RUNS = ("ASPHALT_00", "FLOORING_04", "SNOW_10")     # FLOORING_04 has no IMU file
CLASSES = ["ASPHALT", "FLOORING", "ICE", "SANDY_LOAM", "SNOW"]

SPEC = {
    "name": "derived_boreal",
    "robot": "husky",
    "span": "overlap",
    "run_id": "{run}",
    "sides": {"L": [1, 3], "R": [2, 4]},
    "label": {"from": "column", "file": "wheels", "column": "terrain_name", "names": CLASSES},
    "files": {
        "wheels": {"pattern": "{run}_wheels.csv", "time": {"column": "t_ms", "unit": "ms"}, "gap_periods": 2.5,
                   "columns": {
                       "speed_right_mps": {"to": "wheel{i}_omega_radps", "wheels": "R", "unit": "m/s",
                                           "resample": "linear"},
                       "amps_right": {"to": "wheel{i}_current_a", "wheels": "R", "unit": "A"},
                       "speed_left_mps": {"to": "wheel{i}_omega_radps", "wheels": "L", "unit": "m/s",
                                          "resample": "linear"},
                       "amps_left": {"to": "wheel{i}_current_a", "wheels": "L", "unit": "A"}}},
        "imu": {"pattern": "{run}_imu.csv", "optional": True, "time": {"column": "t_ms", "unit": "ms"},
                "gap_periods": 2.5,
                "columns": {
                    "acc_z": {"to": "imu_az_mps2", "unit": "m/s^2"},
                    "gyro_z_dps": {"to": "imu_yaw_rate_radps", "unit": "deg/s"},
                    "acc_x": {"to": "imu_ax_mps2"}, "acc_y": {"to": "imu_ay_mps2"},
                    "gyro_x_dps": {"to": "imu_roll_rate_radps", "unit": "deg/s"},
                    "gyro_y_dps": {"to": "imu_pitch_rate_radps", "unit": "deg/s"}}},
    },
}


@pytest.fixture(scope="module")
def derived(tmp_path_factory):
    root = tmp_path_factory.mktemp("derived")
    runs = load_dataset_spec("borealtc").discover(BOREAL)
    picked = [r for r in runs if r.run_id in RUNS]
    for r in picked:
        pro = pd.read_csv(r.files["pro"])
        pd.DataFrame({"amps_left": pro["curL"], "speed_right_mps": pro["velR"], "terrain_name": r.fields["label"],
                      "t_ms": pro["time"] * 1000.0, "amps_right": pro["curR"], "speed_left_mps": pro["velL"]}
                     ).to_csv(root / f"{r.run_id}_wheels.csv", index=False)
        if r.files["imu"] is not None:
            imu = pd.read_csv(r.files["imu"])
            pd.DataFrame({"gyro_z_dps": np.degrees(imu["wz"]), "acc_z": imu["az"], "t_ms": imu["time"] * 1000.0,
                          "acc_x": imu["ax"], "gyro_x_dps": np.degrees(imu["wx"]), "acc_y": imu["ay"],
                          "gyro_y_dps": np.degrees(imu["wy"])}).to_csv(root / f"{r.run_id}_imu.csv", index=False)
    (root / "spec.yaml").write_text(yaml.safe_dump(SPEC, sort_keys=False))
    return root, picked


def test_user_spec_gives_the_builtin_tables(derived):
    root, picked = derived
    tables, report = load_dataset(root / "spec.yaml", root)
    got = dict(zip(report.run_ids, tables))
    assert sorted(got) == sorted(RUNS)
    for r in picked:
        want = load_dataset_run(load_dataset_spec("borealtc"), r, label_names=CLASSES).table
        df = got[r.run_id]
        assert len(df) == len(want), r.run_id
        assert df.attrs["terrainml"]["classes"] == CLASSES
        assert (df["terrain"] == CLASSES.index(r.fields["label"])).all()
        for c in want.columns:
            if c in ("run_id",):
                continue
            a, b = want[c].to_numpy(), df[c].to_numpy()
            if a.dtype == bool:
                assert (a == b).all(), (r.run_id, c)
            else:
                np.testing.assert_allclose(b.astype(float), a.astype(float), rtol=1e-9, atol=1e-9,
                                           err_msg=f"{r.run_id} {c}")
