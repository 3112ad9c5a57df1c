"""Ingest of hand-made tables: MCAP round trip, CSV/Parquet, resampling rules, T265 path, inspect."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pandas as pd
import pytest
from mcap.reader import make_reader
from typer.testing import CliRunner

from terrainml.cli import app
from terrainml.io import t265, topics
from terrainml.io.ingest import load_run
from terrainml.io.ingest.resample import resample
from terrainml.io.inspect import inspect_log
from terrainml.io.mcap_writer import RosMcapWriter, write_run_mcap
from terrainml.robot import load_robot
from terrainml.schema import write_run_parquet


def handmade_table(n=400, rate=100.0):
    t = np.arange(n) / rate
    d = {"t_s": t}
    for i in range(1, 4):
        d[f"wheel{i}_omega_radps"] = 5.0 + np.sin(t + i)
        d[f"wheel{i}_steer_rad"] = 0.1 * i * np.ones(n)
        d[f"wheel{i}_current_a"] = 2.0 + 0.5 * np.cos(t * i)
    d.update(imu_ax_mps2=0.3 * np.sin(t), imu_ay_mps2=0.1 * np.ones(n), imu_az_mps2=9.81 * np.ones(n),
             imu_yaw_rate_radps=0.25 * np.ones(n))
    d.update(cam_vx_mps=1.0 + 0.1 * t, cam_vy_mps=0.05 * np.ones(n), cam_yaw_rate_radps=0.25 * np.ones(n),
             cam_yaw_rad=0.25 * t, cam_confidence=np.where((t > 1.0) & (t < 1.2), 1.0, 3.0))
    d.update(cmd_vx_mps=np.ones(n), cmd_vy_mps=np.zeros(n), cmd_yaw_rate_radps=0.25 * np.ones(n),
             terrain=np.where(t < 2.0, 2, 6))
    d.update(gt_vx_mps=np.ones(n), gt_vy_mps=np.zeros(n), gt_yaw_rate_radps=0.25 * np.ones(n),
             gt_x_m=t, gt_y_m=np.zeros(n), gt_yaw_rad=t265.wrap_angle(0.25 * t + 3.0))
    for i in range(1, 4):
        d[f"gt_slip{i}"] = 0.01 * i * np.ones(n)
        d[f"gt_state{i}"] = np.where(t < 1.5, "traction", "steady")
    return pd.DataFrame(d)


def test_handmade_table_round_trips_through_mcap(tmp_path):
    df = handmade_table()
    path = write_run_mcap(df, tmp_path / "hand.mcap", load_robot())
    r = load_run(path)
    out = r.table
    assert r.report.usable and len(out) == len(df)
    for c in df.columns:
        if c in ("terrain",) or c.startswith("gt_state"):
            assert (out[c].to_numpy() == df[c].to_numpy()).all(), c
        elif c.endswith("yaw_rad"):
            np.testing.assert_allclose(t265.wrap_angle(out[c] - df[c]), 0.0, atol=1e-9, err_msg=c)
        else:
            ok = out["cam_valid"] if c == "cam_confidence" else slice(None)
            np.testing.assert_allclose(out[c][ok], df[c][ok], atol=1e-9, err_msg=c)
    # low confidence (< 2) marks the camera invalid there, and only there
    low = df["cam_confidence"] < 2
    assert not out.loc[low, "cam_valid"].any() and out.loc[~low, "cam_valid"].all()
    meta = out.attrs["terrainml"]
    assert meta["rate_hz"] == 100.0 and len(meta["source_sha256"]) == 64 and meta["run_id"] == "hand"
    # gt truth columns exist with the contract names
    for c in ("gt_vx_mps", "gt_slip1", "gt_state3"):
        assert c in out


def test_imu_yaw_and_metadata_round_trip_through_mcap_on_a_rotated_imu_mount(tmp_path):
    """``imu_yaw_rad`` travels as the IMU orientation (through the mount and back, across +-pi);
    a non-finite yaw is read back as none; the ``metadata`` dict is the MCAP's ``terrainml`` record."""
    base = load_robot()
    robot = dataclasses.replace(base, imu=dataclasses.replace(base.imu, roll_rad=0.1, pitch_rad=-0.05, yaw_rad=0.3))
    df = handmade_table(300)
    yaw = t265.wrap_angle(2.9 + 1.5 * df["t_s"].to_numpy())   # wraps through +pi at t ~ 0.26 s
    yaw[100:110] = np.nan
    df["imu_yaw_rad"] = yaw
    path = write_run_mcap(df, tmp_path / "yaw.mcap", robot, metadata={"classes": json.dumps(["a", "b"]), "n": 3})
    out = load_run(path, robot=robot).table
    ok = np.isfinite(yaw)
    np.testing.assert_allclose(t265.wrap_angle(out["imu_yaw_rad"].to_numpy()[ok] - yaw[ok]), 0.0, atol=1e-9)
    assert np.isnan(out["imu_yaw_rad"].to_numpy()[103:107]).all()  # not bridged across the 0.1 s gap
    for c in ("imu_ax_mps2", "imu_ay_mps2", "imu_az_mps2", "imu_yaw_rate_radps"):  # the mount undone too
        np.testing.assert_allclose(out[c], df[c], atol=1e-9, err_msg=c)
    assert out["imu_valid"].all()
    with open(path, "rb") as f:
        (meta,) = list(make_reader(f).iter_metadata())
    assert meta.name == "terrainml" and meta.metadata == {"classes": '["a", "b"]', "n": "3"}
    # without the column the IMU has no orientation and ingest makes no yaw (as before)
    plain = load_run(write_run_mcap(handmade_table(100), tmp_path / "plain.mcap", robot), robot=robot).table
    assert "imu_yaw_rad" not in plain or plain["imu_yaw_rad"].isna().all()


def test_parquet_and_csv_inputs(tmp_path):
    df = handmade_table(200)
    pq = write_run_parquet(df, tmp_path / "a.parquet")
    r = load_run(pq)
    assert r.report.usable and len(r.table) == 200
    np.testing.assert_allclose(r.table["wheel2_current_a"], df["wheel2_current_a"], atol=1e-12)
    # CSV with the robot's own names and millisecond time, through a column map
    csv = tmp_path / "b.csv"
    names = {"imu_ax_mps2": "acc_x", "imu_ay_mps2": "acc_y", "imu_az_mps2": "acc_z", "imu_yaw_rate_radps": "gz",
             "wheel1_omega_radps": "w1", "wheel2_omega_radps": "w2", "wheel3_omega_radps": "w3"}
    raw = pd.DataFrame({"time_ms": df["t_s"] * 1000 + 5000, **{v: df[k] for k, v in names.items()}})
    raw.to_csv(csv, index=False)
    cmap = {"time_column": "time_ms", "time_scale": 0.001, "columns": {v: k for k, v in names.items()}}
    r = load_run(csv, topic_map=cmap)
    assert r.report.usable and r.table["imu_valid"].all() and r.table["wheels_valid"].all()
    assert not r.table["current_valid"].any() and not r.table["steer_valid"].any()
    assert r.table["t_s"].iloc[0] == 0.0 and len(r.table) == 200
    np.testing.assert_allclose(r.table["wheel1_omega_radps"], df["wheel1_omega_radps"], atol=1e-9)
    assert not r.table["cam_valid"].any()
    assert any("missing" in w for w in r.report.warnings)


def test_resample_rules_hand_worked():
    t_src = np.array([0.0, 0.02, 0.04, 0.10, 0.12])
    v = np.array([0.0, 2.0, 4.0, 10.0, np.inf])
    grid = np.arange(14) / 100.0
    lin, ok = resample(t_src, v, grid, method="linear", max_gap_s=0.02)
    np.testing.assert_allclose(lin[:5], [0, 1, 2, 3, 4])          # interpolation inside 20 ms gaps
    assert not ok[5:10].any()                                     # never across the 60 ms gap
    assert ok[10] and lin[10] == 10.0
    assert not ok[11:].any()                                      # Inf sample, then past the end
    prev, okp = resample(t_src, v, grid, method="previous", max_gap_s=0.02)
    np.testing.assert_allclose(prev[:7], [0, 0, 2, 2, 4, 4, 4])   # nearest previous, 20 ms hold
    assert okp[:7].all() and not okp[7:10].any()
    ang, oka = resample(np.array([0.0, 0.1]), np.array([3.1, -3.1]), np.array([0.05]), method="angle",
                        max_gap_s=1.0)
    assert abs(abs(ang[0]) - np.pi) < 1e-9                        # through +-pi, not through 0


def test_gap_longer_than_two_base_periods_is_invalid(tmp_path):
    path = tmp_path / "gap.mcap"
    with RosMcapWriter(path, 3) as w:
        for k in range(100):
            t = k / 100
            if 0.30 <= t < 0.34:   # 50 ms gap (> 2 base periods of 10 ms)
                continue
            w.write_imu(t, (0, 0, 9.81), (0, 0, 0))
            w.write_wheel_joints(t, [1, 1, 1], [0, 0, 0])
    r = load_run(path)
    t = r.table
    gap = (t["t_s"] > 0.29 + 1e-9) & (t["t_s"] < 0.34 - 1e-9)
    assert not t.loc[gap, "imu_valid"].any() and t.loc[~gap, "imu_valid"].all()
    # encoders hold the previous sample for at most 2 base periods (0.30, 0.31), then go invalid
    held = t["t_s"].round(2).isin([0.30, 0.31])
    assert t.loc[held, "wheels_valid"].all() and not t.loc[gap & ~held, "wheels_valid"].any()
    info = inspect_log(path)
    assert info["topics"][topics.IMU]["gaps"] == 1
    assert info["topics"][topics.IMU]["max_gap_s"] == pytest.approx(0.05, abs=1e-6)


def test_imu_mount_rotation_from_spec_and_topic_map(tmp_path):
    path = tmp_path / "rot.mcap"
    with RosMcapWriter(path, 4) as w:
        for k in range(50):
            w.write_imu(k / 100, (0.0, 9.81, 0.0), (0.0, 0.3, 0.0))   # gravity on sensor +y
            w.write_wheel_joints(k / 100, [1] * 4, [0] * 4)
    r = load_run(path, robot=load_robot("husky"))  # husky spec: +90 deg about x
    assert r.table["imu_az_mps2"].median() == pytest.approx(9.81)
    assert r.table["imu_yaw_rate_radps"].median() == pytest.approx(0.3)
    from terrainml.io.topicmap import load_topic_map

    m = load_topic_map().to_dict()
    m["imu_mount"] = {"roll_rad": 0.0, "pitch_rad": 0.0, "yaw_rad": 0.0}
    r = load_run(path, robot=load_robot("husky"), topic_map=m)                 # override: no rotation
    assert r.table["imu_ay_mps2"].median() == pytest.approx(9.81)


def test_inspect_cli_json(good_log):
    path, counts = good_log
    res = CliRunner().invoke(app, ["inspect", str(path), "--json"])
    assert res.exit_code == 0
    info = json.loads(res.stdout)
    assert info["messages"] == sum(counts.values())
    assert info["topics"][topics.IMU]["count"] == counts[topics.IMU]
    assert info["topics"][topics.IMU]["rate_hz"] == pytest.approx(100.0, rel=1e-6)
    assert info["span_s"] == pytest.approx(2.99)
    res = CliRunner().invoke(app, ["inspect", str(path)])
    assert res.exit_code == 0 and topics.CAMERA_ODOM in res.stdout


def test_ros2_bag_folder_with_one_mcap(tmp_path, good_log):
    import shutil

    folder = tmp_path / "rosbag2_run"
    folder.mkdir()
    shutil.copy(good_log[0], folder / "rosbag2_run_0.mcap")
    r = load_run(folder)
    assert r.report.usable and len(r.table) == 300
