"""BorealTC through its built-in dataset spec, on the real public data (../shared/datasets/borealtc)."""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from terrainml.io.ingest import load_dataset, load_dataset_run, load_run
from terrainml.io.ingest.dataset_spec import DatasetSpecError, load_dataset_spec

ROOT = Path(__file__).resolve().parents[2].parent / "shared" / "datasets" / "borealtc"
pytestmark = pytest.mark.skipif(not ROOT.is_dir(), reason=f"real dataset not present at {ROOT}")


def test_discovers_all_runs_and_missing_imu():
    spec = load_dataset_spec("borealtc")
    runs = spec.discover(ROOT)
    classes = spec.label_names(runs)
    assert classes == ["ASPHALT", "FLOORING", "ICE", "SANDY_LOAM", "SNOW"]
    counts = {c: sum(r.fields["label"] == c for r in runs) for c in classes}
    # SOURCE.md: ASPHALT 7, FLOORING 10, ICE 13, SANDY_LOAM 14, SNOW 27
    assert counts == {"ASPHALT": 7, "FLOORING": 10, "ICE": 13, "SANDY_LOAM": 14, "SNOW": 27}
    missing = sorted(r.run_id for r in runs if r.files["imu"] is None)
    assert missing == ["FLOORING_04", "FLOORING_06", "ICE_01"]


def test_run_table_units_and_gravity():
    spec = load_dataset_spec("borealtc")
    runs = spec.discover(ROOT)
    classes = spec.label_names(runs)
    run = next(r for r in runs if r.run_id == "ASPHALT_00")
    df = load_dataset_run(spec, run, label_names=classes).table
    raw = pd.read_csv(run.files["pro"])
    assert df["t_s"].iloc[-1] == pytest.approx(raw["time"].iloc[-1], abs=0.2)
    assert np.diff(df["t_s"]).mean() == pytest.approx(0.01)
    assert df["imu_az_mps2"].mean() == pytest.approx(9.8, abs=0.3)
    # left motor speed (m/s) / radius on wheels 1 and 3
    assert df["wheel1_omega_radps"].median() * 0.1651 == pytest.approx(raw["velL"].median(), rel=0.05)
    assert (df["wheel1_current_a"] == df["wheel3_current_a"]).all()
    assert df.attrs["terrainml"]["classes"] == classes
    assert (df["terrain"] == 0).all()


def test_columns_found_by_header_name_not_position(tmp_path):
    cls = tmp_path / "GRAVEL"
    cls.mkdir()
    (cls / "pro_00.csv").write_text("velR,time,curR,velL,curL\n" + "\n".join(
        f"0.5,{k * 0.15},2.0,0.4,1.0" for k in range(40)))
    (cls / "imu_00.csv").write_text("az,ay,ax,time,wz,wy,wx\n" + "\n".join(
        f"9.8,0.0,0.1,{k * 0.01},0.2,0.0,0.0" for k in range(600)))
    tables, report = load_dataset("borealtc", tmp_path)
    df = tables[0]
    assert report.classes == ["GRAVEL"]
    assert df["wheel2_omega_radps"].iloc[10] == pytest.approx(0.5 / 0.1651)
    assert df["wheel1_current_a"].iloc[10] == pytest.approx(1.0)
    assert df["imu_yaw_rate_radps"].iloc[10] == pytest.approx(0.2)
    assert df["imu_valid"].all() and df["wheels_valid"].all()


def test_missing_column_named(tmp_path):
    cls = tmp_path / "ICE"
    cls.mkdir()
    (cls / "pro_00.csv").write_text("time,curL,velL,velR\n0,1,1,1\n0.1,1,1,1\n")
    res = load_run(cls / "pro_00.csv", dataset="borealtc")
    assert not res.report.usable
    assert any("pro_00.csv: missing column 'curR'" in e for e in res.report.errors), res.report.errors


def test_not_a_folder(tmp_path):
    with pytest.raises(DatasetSpecError, match="not a folder"):
        load_dataset("borealtc", tmp_path / "nope")


def test_any_sampling_rates_resampled_to_100hz(tmp_path):
    # IMU at 200 Hz, wheel service at 10 Hz, both linear in time: linear interpolation onto the
    # 100 Hz grid must reproduce them exactly (hand-worked values)
    cls = tmp_path / "SNOW"
    cls.mkdir()
    (cls / "pro_07.csv").write_text("time,curL,curR,velL,velR\n" + "\n".join(
        f"{k * 0.1},{2 * k * 0.1},{1.0},{0.5},{0.5 + k * 0.01}" for k in range(31)))
    (cls / "imu_07.csv").write_text("time,wx,wy,wz,ax,ay,az\n" + "\n".join(
        f"{k * 0.005},0,0,{k * 0.005},0,0,9.81" for k in range(601)))
    tables, report = load_dataset("borealtc", tmp_path)
    df = tables[0]
    assert report.runs == 1 and report.classes == ["SNOW"]
    assert np.diff(df["t_s"]).mean() == pytest.approx(0.01)
    assert df["t_s"].iloc[-1] == pytest.approx(3.0)
    k = int(np.argmin(np.abs(df["t_s"] - 1.23)))
    assert df["wheel1_current_a"].iloc[k] == pytest.approx(2 * 1.23)
    assert df["wheel3_current_a"].iloc[k] == pytest.approx(2 * 1.23)
    assert df["imu_yaw_rate_radps"].iloc[k] == pytest.approx(1.23)
    assert df["wheel4_omega_radps"].iloc[k] == pytest.approx((0.5 + 0.123) / 0.1651)
    assert df["imu_valid"].all() and df["wheels_valid"].all()


def test_cli_ingest_one_run_with_the_builtin_spec(tmp_path):
    from typer.testing import CliRunner

    from terrainml.cli import app
    from terrainml.schema import read_run_parquet

    out = tmp_path / "ice03.parquet"
    res = CliRunner().invoke(app, ["ingest", str(ROOT / "ICE" / "pro_03.csv"), "--format", "borealtc",
                                   "--out", str(out), "-q"])
    assert res.exit_code == 0, res.output
    df = read_run_parquet(out)
    meta = df.attrs["terrainml"]
    assert meta["classes"] == ["ASPHALT", "FLOORING", "ICE", "SANDY_LOAM", "SNOW"]
    assert meta["files"]["imu"].endswith("imu_03.csv")
    assert (df["terrain"] == 2).all() and df["run_id"].iloc[0] == "ICE_03"
    assert df["imu_valid"].mean() > 0.99


def test_unknown_folder_label_is_an_error_naming_it(tmp_path):
    spec = load_dataset_spec("borealtc")
    spec.label = type(spec.label)(source="folder", names=("ASPHALT",))
    with pytest.raises(DatasetSpecError, match=r"FLOORING/pro_00\.csv: label 'FLOORING' \(from the folder\)"):
        load_dataset(spec, ROOT)
