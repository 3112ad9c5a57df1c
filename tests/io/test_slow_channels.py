"""Low-rate channels on the 100 Hz grid: a 15 Hz wheel log at constant speed stays constant.

Ground truth: the robot drives straight at 0.56 m/s, so every resampled wheel speed is
0.56 / R and the EKF's dynamic state is never "braking" (1,642 of 2,035 ticks were).
"""

import numpy as np
import pandas as pd
import pytest

from terrainml.estimation.run import estimate_run
from terrainml.io.ingest import load_dataset
from terrainml.io.ingest import load_run
from terrainml.io.mcap_writer import RosMcapWriter
from terrainml.robot import load_robot

V_MPS, R, SPAN_S = 0.56, 0.1651, 20.35


def _stamps_15hz(seed: int = 0) -> np.ndarray:
    """15 Hz with a real logger's jitter (62-71 ms)."""
    t = np.concatenate([[0.0], np.cumsum(np.random.default_rng(seed).uniform(0.062, 0.071, 400))])
    return t[t <= SPAN_S]


def _check(df: pd.DataFrame) -> None:
    assert df["wheels_valid"].mean() > 0.99
    for i in range(1, 5):
        w = df.loc[df["wheels_valid"], f"wheel{i}_omega_radps"] * R
        assert np.abs(w - V_MPS).max() < 1e-9


def _imu_rows(t):
    rng = np.random.default_rng(1)
    return pd.DataFrame({"time": t, "wx": 0.0, "wy": 0.0, "wz": rng.normal(0, 0.003, len(t)),
                         "ax": rng.normal(0, 0.03, len(t)), "ay": rng.normal(0, 0.03, len(t)),
                         "az": 9.81 + rng.normal(0, 0.03, len(t))})


def test_15hz_wheels_borealtc_layout_constant_and_not_braking(tmp_path):
    (tmp_path / "CONCRETE").mkdir()
    tw = _stamps_15hz()
    pd.DataFrame({"time": tw, "curL": 3.0, "curR": 3.0, "velL": V_MPS, "velR": V_MPS}).to_csv(
        tmp_path / "CONCRETE" / "pro_00.csv", index=False)
    _imu_rows(np.arange(0, SPAN_S, 0.01)).to_csv(tmp_path / "CONCRETE" / "imu_00.csv", index=False)
    tables, _ = load_dataset("borealtc", tmp_path)
    df = tables[0]
    _check(df)
    est = estimate_run(df, load_robot("husky"), "robust")
    braking = sum(int((est[f"state{i}"] == "braking").sum()) for i in range(1, 5)) / (4 * len(est))
    assert braking < 0.02


def test_15hz_wheels_in_a_sparse_table_sharing_stamps_with_the_imu(tmp_path):
    # one CSV, IMU rows at 100 Hz and wheel rows at 15 Hz, stamps written to 10 ms: most wheel rows
    # share their stamp with an IMU row (and come after it); no wheel sample may be lost
    tw = np.round(_stamps_15hz(), 2)
    imu = _imu_rows(np.round(np.arange(0, SPAN_S, 0.01), 2)).rename(columns={
        "time": "t_s", "ax": "imu_ax_mps2", "ay": "imu_ay_mps2", "az": "imu_az_mps2", "wz": "imu_yaw_rate_radps"})
    wheels = pd.DataFrame({"t_s": tw, **{f"wheel{i}_omega_radps": V_MPS / R for i in range(1, 5)},
                           **{f"wheel{i}_current_a": 3.0 for i in range(1, 5)}})
    table = pd.concat([imu.drop(columns=["wx", "wy"]), wheels]).sort_values("t_s", kind="stable")
    table.to_csv(tmp_path / "run.csv", index=False)
    res = load_run(tmp_path / "run.csv", robot=load_robot("husky"))
    assert res.report.usable, res.report.errors
    _check(res.table)
    assert res.table["wheels_valid"].iloc[:10].all()        # the first wheel sample is at t = 0


def test_15hz_wheels_mcap(tmp_path):
    tw = _stamps_15hz()
    ti = np.arange(0, SPAN_S, 0.01)
    events = sorted([(t, 1) for t in tw] + [(t, 0) for t in ti])
    with RosMcapWriter(tmp_path / "run.mcap", 4) as w:
        for t, kind in events:
            if kind:
                w.write_wheel_joints(t, np.full(4, V_MPS / R), np.zeros(4))
                w.write_motor_current(t, np.full(4, 3.0))
            else:
                w.write_imu(t, np.array([0.0, 0.0, 9.81]), np.zeros(3))
    res = load_run(tmp_path / "run.mcap", robot=load_robot("husky"))
    assert res.report.usable, res.report.errors
    _check(res.table)


@pytest.mark.parametrize("method", ["linear", "previous"])
def test_resample_holds_or_interpolates_a_slow_constant(method):
    from terrainml.io.ingest.resample import gap_threshold_s, resample

    t = _stamps_15hz(3)
    grid = np.arange(0, t[-1], 0.01)
    out, valid = resample(t, np.full(len(t), V_MPS), grid, method=method, max_gap_s=gap_threshold_s(t, 100.0))
    assert valid.all() and np.abs(out - V_MPS).max() < 1e-12
