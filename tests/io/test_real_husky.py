"""Real data: robot_localization's test1.bag (a real Clearpath Husky, ROS 1, bz2 chunks)."""

from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from terrainml.cli import app
from terrainml.io.ingest import load_run
from terrainml.robot import load_robot

BAG = Path("/work/shared/datasets/robot_localization_husky/test1.bag")
if not BAG.is_file():  # the dataset may live next to the checkout
    BAG = Path(__file__).resolve().parents[2].parent / "shared/datasets/robot_localization_husky/test1.bag"
pytestmark = pytest.mark.skipif(not BAG.is_file(), reason="test1.bag not available")


@pytest.fixture(scope="module")
def husky():
    return load_run(BAG, robot=load_robot("husky"), topic_map="husky_robot_localization")


def test_rows_and_span(husky):
    rep = husky.report
    assert rep.usable and not rep.errors
    # SOURCE.md: 395 s; 11,865 IMU and 3,952 wheel-odometry messages
    assert rep.topics["/imu/data"]["decoded"] == 11865
    assert rep.topics["/husky_velocity_controller/odom"]["decoded"] == 3952
    assert husky.table["t_s"].iloc[-1] == pytest.approx(395.3, abs=0.5)
    assert len(husky.table) == pytest.approx(39535, abs=50)
    assert husky.table["imu_valid"].mean() > 0.99 and husky.table["wheels_valid"].mean() > 0.99


def test_gravity_on_plus_z_after_mount_rotation(husky):
    t = husky.table
    az = t.loc[t["imu_valid"], "imu_az_mps2"]
    assert az.median() == pytest.approx(9.8, abs=0.15)
    assert abs(t.loc[t["imu_valid"], "imu_ay_mps2"].median()) < 0.5


def test_wheel_speeds_from_body_twist_agree_with_gyro(husky):
    # skid-steer yaw rate from the derived left/right wheel speeds must track the (rotated) gyro
    rb = load_robot("husky")
    t = husky.table
    m = (t["imu_valid"] & t["wheels_valid"]).to_numpy()
    track = 2 * 0.2854
    r_wheels = (t["wheel2_omega_radps"] - t["wheel1_omega_radps"]) * rb.wheel_radius_m / track
    assert np.corrcoef(r_wheels[m], t["imu_yaw_rate_radps"][m])[0, 1] > 0.8
    # forward drive: mean wheel speed ~ 1 m/s most of the run
    v = 0.5 * (t["wheel1_omega_radps"] + t["wheel2_omega_radps"]) * rb.wheel_radius_m
    assert 0.5 < np.median(v[m]) < 1.5
    assert (t["current_valid"] == False).all()  # noqa: E712 - no current in this bag


def test_cli_ingest_and_inspect(tmp_path):
    runner = CliRunner()
    out = tmp_path / "husky.parquet"
    res = runner.invoke(app, ["ingest", str(BAG), "--out", str(out), "--robot", "husky",
                              "--topics", "husky_robot_localization", "-q"])
    assert res.exit_code == 0, res.output
    from terrainml.schema import read_run_parquet

    df = read_run_parquet(out)
    assert df.attrs["terrainml"]["run_id"] == "test1" and len(df) > 39000
    res = runner.invoke(app, ["inspect", str(BAG), "--json"])
    assert res.exit_code == 0
    import json

    info = json.loads(res.stdout)
    assert info["topics"]["/imu/data"]["rate_hz"] == pytest.approx(30, abs=1)
    assert info["span_s"] == pytest.approx(395.3, abs=0.5)
