"""Dataset specs: multi-file CSV/Parquet layouts reach the canonical run table without code."""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from typer.testing import CliRunner

from terrainml.cli import app
from terrainml.io.ingest import load_dataset, load_run
from terrainml.io.ingest.dataset_spec import DatasetSpecError, load_dataset_spec, parse_dataset_spec
from terrainml.schema import read_run_parquet

R_HUSKY = 0.1651

SPEC = {
    "name": "field_trials",
    "robot": "husky",
    "run_id": "trial_{run}",
    "sides": {"left": [1, 3], "right": [2, 4]},
    "label": {"from": "column", "file": "wheels", "column": "surface"},
    "files": {
        "wheels": {
            "pattern": "wheels_{run}.csv",
            "time": {"column": "stamp_ms", "unit": "ms"},
            "columns": {
                "v_right": {"to": "wheel{i}_omega_radps", "wheels": "right", "unit": "m/s"},
                "v_left": {"to": "wheel{i}_omega_radps", "wheels": "left", "unit": "m/s"},
                "i_left": {"to": "wheel{i}_current_a", "wheels": "left", "unit": "mA"},
                "i_right": {"to": "wheel{i}_current_a", "wheels": "right", "unit": "mA"},
            },
        },
        "imu": {
            "pattern": "imu_{run}.parquet",
            "optional": True,
            "time": {"column": "t", "unit": "s"},
            "columns": {
                "gz_dps": {"to": "imu_yaw_rate_radps", "unit": "deg/s"},
                "acc_x_g": {"to": "imu_ax_mps2", "unit": "g"},
                "acc_y_g": {"to": "imu_ay_mps2", "unit": "g"},
                "acc_z_g": {"to": "imu_az_mps2", "unit": "g"},
            },
        },
    },
}


def _runs(spec, root) -> dict:
    """Every usable run of a dataset folder by run id."""
    tables, report = load_dataset(spec, root)
    return dict(zip(report.run_ids, tables))


def _write_run(root: Path, run: str, surfaces, n_w: int = 60, imu: bool = True) -> None:
    """Wheels at 10 Hz (ms stamps, m/s, mA, string labels), IMU at 100 Hz (deg/s, g)."""
    t_ms = np.arange(n_w) * 100
    lab = [surfaces[min(k * len(surfaces) // n_w, len(surfaces) - 1)] for k in range(n_w)]
    pd.DataFrame({"surface": lab, "i_right": 2500.0, "v_left": 0.4, "stamp_ms": t_ms, "v_right": 0.6,
                  "i_left": 1500.0}).to_csv(root / f"wheels_{run}.csv", index=False)
    if imu:
        t = np.arange(0, (n_w - 1) * 0.1 + 1e-9, 0.01)
        pd.DataFrame({"t": t, "acc_z_g": 1.0, "acc_x_g": 0.1, "acc_y_g": 0.0,
                      "gz_dps": 90.0}).to_parquet(root / f"imu_{run}.parquet")


@pytest.fixture()
def dataset(tmp_path):
    _write_run(tmp_path, "01", ["gravel", "grass"])
    _write_run(tmp_path, "02", ["mud"], imu=False)
    spec_path = tmp_path / "spec.yaml"
    spec_path.write_text(yaml.safe_dump(SPEC, sort_keys=False))
    return tmp_path, spec_path


def test_units_sides_and_string_labels(dataset):
    root, spec = dataset
    res = load_run(root / "wheels_01.csv", dataset=spec)
    assert res.report.usable, res.report.errors
    df = res.table
    assert np.diff(df["t_s"]).mean() == pytest.approx(0.01)
    # hand-worked: m/s / R -> rad/s, left to wheels 1 and 3; mA -> A; deg/s -> rad/s; g -> m/s^2
    assert df["wheel1_omega_radps"].iloc[50] == pytest.approx(0.4 / R_HUSKY)
    assert df["wheel3_omega_radps"].iloc[50] == pytest.approx(0.4 / R_HUSKY)
    assert df["wheel2_omega_radps"].iloc[50] == pytest.approx(0.6 / R_HUSKY)
    assert df["wheel4_current_a"].iloc[50] == pytest.approx(2.5)
    assert df["wheel1_current_a"].iloc[50] == pytest.approx(1.5)
    assert df["imu_yaw_rate_radps"].iloc[50] == pytest.approx(np.pi / 2)
    assert df["imu_az_mps2"].iloc[50] == pytest.approx(9.80665)
    assert df["imu_valid"].all() and df["wheels_valid"].all()
    meta = df.attrs["terrainml"]
    assert meta["classes"] == ["grass", "gravel"]          # this run's labels, sorted
    # first half gravel (id 1), second half grass (id 0), held per row
    assert df["terrain"].iloc[10] == 1 and df["terrain"].iloc[-10] == 0
    assert df["run_id"].iloc[0] == "trial_01"


def test_dataset_runs_share_class_ids(dataset):
    root, spec = dataset
    runs = _runs(spec, root)
    assert sorted(runs) == ["trial_01", "trial_02"]
    for df in runs.values():
        assert df.attrs["terrainml"]["classes"] == ["grass", "gravel", "mud"]
    assert set(runs["trial_02"]["terrain"]) == {2}
    assert not runs["trial_02"]["imu_valid"].any()          # optional IMU file absent


def test_unknown_label_is_an_error_naming_file_and_value(dataset):
    root, _ = dataset
    spec = {**SPEC, "label": {**SPEC["label"], "names": ["gravel", "mud"]}}
    res = load_run(root / "wheels_01.csv", dataset=spec)
    assert not res.report.usable
    assert any("wheels_01.csv: column 'surface': label 'grass'" in e for e in res.report.errors)


def test_missing_column_named(dataset):
    root, _ = dataset
    df = pd.read_csv(root / "wheels_01.csv").drop(columns=["i_left"])
    df.to_csv(root / "wheels_01.csv", index=False)
    res = load_run(root / "wheels_01.csv", dataset=SPEC)
    assert any("wheels_01.csv: missing column 'i_left'" in e for e in res.report.errors)


def test_label_from_file_and_folder(tmp_path):
    for cls, run in (("sand", "a"), ("clay", "b")):
        (tmp_path / cls).mkdir()
        pd.DataFrame({"time": np.arange(30) * 0.1, "w": 1.0}).to_csv(tmp_path / cls / f"w_{run}.csv", index=False)
    folder = {"name": "f", "robot": "husky", "label": {"from": "folder"},
              "files": {"w": {"pattern": "{label}/w_{run}.csv",
                              "columns": {"w": {"to": "wheel{i}_omega_radps", "wheels": [1, 2, 3, 4]}}}}}
    runs = _runs(folder, tmp_path)
    assert runs["clay_b"].attrs["terrainml"]["classes"] == ["clay", "sand"]
    assert set(runs["sand_a"]["terrain"]) == {1}
    (tmp_path / "labels.csv").write_text("run,terrain\na,wet\nb,dry\n")
    by_file = {**folder, "label": {"from": "file", "path": "labels.csv", "key": "run", "column": "terrain"}}
    runs = _runs(by_file, tmp_path)
    assert runs["sand_a"].attrs["terrainml"]["classes"] == ["dry", "wet"]
    assert set(runs["sand_a"]["terrain"]) == {1} and set(runs["clay_b"]["terrain"]) == {0}


@pytest.mark.parametrize("patch, match", [
    ({"files": {"w": {"pattern": "w_{run}.csv", "columns": {"a": {"to": "speed"}}}}}, "not a canonical column"),
    ({"files": {"w": {"pattern": "w_{run}.csv", "columns": {"a": {"to": "wheel{i}_omega_radps"}}}}}, "needs 'wheels'"),
    ({"files": {"w": {"pattern": "w_{run}.csv",
                      "columns": {"a": {"to": "imu_ax_mps2", "unit": "deg"}}}}}, "unit 'deg' cannot become m/s"),
    ({"span": "some"}, "'span' must be one of"),
    ({"label": {"from": "folder"}}, "field '{label}' is not in the first file's pattern"),
])
def test_bad_specs_refused_naming_the_entry(patch, match):
    base = {"name": "x", "files": {"w": {"pattern": "w_{run}.csv", "columns": {"a": "imu_ax_mps2"}}}}
    with pytest.raises(DatasetSpecError, match=match):
        parse_dataset_spec({**base, **patch}, "x.yaml")


def test_builtin_borealtc_spec_loads():
    spec = load_dataset_spec("borealtc")
    assert [f.role for f in spec.files] == ["pro", "imu"] and spec.sides["left"] == (1, 3)


def test_cli_ingest_with_a_spec(dataset, tmp_path):
    root, spec = dataset
    out = tmp_path / "run.parquet"
    res = CliRunner().invoke(app, ["ingest", str(root / "imu_01.parquet"), "--format", str(spec), "--out", str(out)])
    assert res.exit_code == 0, res.output
    df = read_run_parquet(out)
    assert df.attrs["terrainml"]["classes"] == ["grass", "gravel"]
    assert df["wheel2_omega_radps"].iloc[5] == pytest.approx(0.6 / R_HUSKY)
    bad = CliRunner().invoke(app, ["ingest", str(root / "other.csv"), "--format", str(spec), "--out", str(out)])
    assert bad.exit_code == 2


@pytest.mark.parametrize("pattern", ["../imu_{run}.parquet", "sub/../../imu_{run}.parquet",
                                     "/tmp/imu_{run}.parquet", "~/imu_{run}.parquet"])
def test_spec_reading_outside_its_folder_is_refused_unless_allowed(tmp_path, pattern):
    """A spec's ``../imu_{run}.csv`` read outside the dataset folder silently."""
    root = tmp_path / "data"
    root.mkdir()
    _write_run(root, "01", ["gravel"], imu=False)
    _write_run(tmp_path, "01", ["gravel"])           # the IMU file one folder up
    doc = yaml.safe_load(yaml.safe_dump(SPEC, sort_keys=False))
    doc["files"]["imu"]["pattern"] = pattern
    spec_path = root / "spec.yaml"
    spec_path.write_text(yaml.safe_dump(doc, sort_keys=False))
    with pytest.raises(DatasetSpecError) as exc:
        load_dataset_spec(spec_path)
    assert str(exc.value) == (f"{spec_path}: file 'imu' pattern {pattern!r} reads outside the dataset "
                              "folder; refused (allow it with --allow-outside-spec-dir)")
    assert load_dataset_spec(spec_path, allow_outside=True).files[1].pattern == pattern
    wheels = root / "wheels_01.csv"
    res = CliRunner().invoke(app, ["ingest", str(wheels), "--format", str(spec_path), "--out",
                                   str(tmp_path / "o.parquet")])
    assert res.exit_code == 2 and "reads outside the dataset folder" in res.output
    assert "Traceback" not in res.output
    if pattern == "../imu_{run}.parquet":   # allowed: the IMU one folder up is read
        res = CliRunner().invoke(app, ["ingest", str(wheels), "--format", str(spec_path), "--out",
                                       str(tmp_path / "o.parquet"), "--allow-outside-spec-dir"])
        assert res.exit_code == 0, res.output
        assert read_run_parquet(tmp_path / "o.parquet")["imu_valid"].any()
