"""ROS 2 bag folders (metadata.yaml + .db3) are read through rosbags.rosbag2.Reader."""

import json

import numpy as np
import pytest
from rosbags.rosbag2 import Writer
from rosbags.typesys import Stores, get_typestore
from typer.testing import CliRunner

from terrainml.cli import app
from terrainml.io.ingest import ingest_to_parquet, load_run
from terrainml.io.inspect import inspect_log
from terrainml.schema import read_run_parquet

T0_NS = 1_700_000_000_000_000_000


@pytest.fixture(scope="module")
def db3_bag(tmp_path_factory):
    """3 s: IMU at 100 Hz (yaw rate 0.1 rad/s), wheel joints of a 3-wheel robot at 20 Hz (2 rad/s)."""
    ts = get_typestore(Stores.LATEST)
    T = ts.types
    path = tmp_path_factory.mktemp("bag") / "run"
    with Writer(path, version=9) as w:
        ci = w.add_connection("/imu", "sensor_msgs/msg/Imu", typestore=ts)
        cj = w.add_connection("/wheels/joint_states", "sensor_msgs/msg/JointState", typestore=ts)
        for k in range(300):
            tn = T0_NS + k * 10_000_000
            h = T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=tn // 10**9, nanosec=tn % 10**9),
                                         frame_id="imu")
            v3 = T["geometry_msgs/msg/Vector3"]
            imu = T["sensor_msgs/msg/Imu"](
                header=h, orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                orientation_covariance=np.zeros(9), angular_velocity=v3(x=0.0, y=0.0, z=0.1),
                angular_velocity_covariance=np.zeros(9), linear_acceleration=v3(x=0.0, y=0.0, z=9.81),
                linear_acceleration_covariance=np.zeros(9))
            w.write(ci, tn, ts.serialize_cdr(imu, "sensor_msgs/msg/Imu"))
            if k % 5 == 0:
                names = [f"wheel{i}_drive" for i in (1, 2, 3)] + [f"wheel{i}_steer" for i in (1, 2, 3)]
                js = T["sensor_msgs/msg/JointState"](header=h, name=names, position=np.zeros(6),
                                                     velocity=np.array([2.0, 2.0, 2.0, 0, 0, 0]), effort=np.zeros(6))
                w.write(cj, tn, ts.serialize_cdr(js, "sensor_msgs/msg/JointState"))
    return path


def test_inspect_accepts_a_db3_folder(db3_bag):
    info = inspect_log(db3_bag)
    assert info["format"] == "rosbag2"
    assert info["topics"]["/imu"]["count"] == 300
    assert info["topics"]["/wheels/joint_states"]["rate_hz"] == pytest.approx(20.0)
    res = CliRunner().invoke(app, ["inspect", str(db3_bag), "--json"])
    assert res.exit_code == 0, res.output
    assert json.loads(res.stdout)["messages"] == 360


def test_ingest_a_db3_folder(db3_bag, tmp_path):
    res = load_run(db3_bag)
    assert res.report.usable, res.report.errors
    df = res.table
    assert df["imu_yaw_rate_radps"].mean() == pytest.approx(0.1)
    assert df["wheel2_omega_radps"][df["wheels_valid"]].mean() == pytest.approx(2.0)
    rep = ingest_to_parquet(db3_bag, tmp_path / "run.parquet")
    assert rep.usable
    back = read_run_parquet(tmp_path / "run.parquet")
    assert np.allclose(back["imu_yaw_rate_radps"], df["imu_yaw_rate_radps"], equal_nan=True)


def test_a_folder_without_metadata_is_refused(tmp_path):
    with pytest.raises(Exception, match="not a ROS 2 bag"):
        inspect_log(tmp_path)
