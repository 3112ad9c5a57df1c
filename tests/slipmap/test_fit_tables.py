"""Fitting a map from canonical run tables recovers a known slippage law."""

import numpy as np
import pandas as pd
from typer.testing import CliRunner

from terrainml.cli import app
from terrainml.robot import load_robot
from terrainml.schema import make_metadata, write_run_parquet
from terrainml.slipmap import SlipMap


def _husky_table(rng, n=1500):
    robot = load_robot("husky")
    R, B = robot.wheel_radius_m, 0.5708
    wl = rng.uniform(1.0, 6.0, n)
    wr = rng.uniform(1.0, 6.0, n)
    beta = lambda w: 0.08 * R * w  # noqa: E731 - true law: 8 % slip on each side
    v_tl, v_tr = R * wl - beta(wl), R * wr - beta(wr)
    vx = 0.5 * (v_tl + v_tr)
    r = (v_tr - v_tl) / B
    df = pd.DataFrame({"t_s": np.arange(n) * 0.01, "imu_ax_mps2": 0.0, "imu_ay_mps2": 0.0,
                       "imu_az_mps2": 9.81, "imu_yaw_rate_radps": r,
                       "gt_vx_mps": vx + rng.normal(0, 0.005, n), "gt_vy_mps": 0.02 * vx,
                       "gt_yaw_rate_radps": r, "terrain": 2})
    for i in range(1, 5):
        df[f"wheel{i}_omega_radps"] = wl if i in (1, 3) else wr
        df[f"wheel{i}_steer_rad"] = 0.0
        df[f"wheel{i}_current_a"] = 0.0
    return df, robot, beta


def test_fit_cli_recovers_known_slip(tmp_path):
    rng = np.random.default_rng(0)
    df, robot, beta = _husky_table(rng)
    write_run_parquet(df, tmp_path / "runs" / "a.parquet", make_metadata(robot_json=robot.to_json()))
    res = CliRunner().invoke(app, ["slipmap", "fit", str(tmp_path / "runs"), "--out", str(tmp_path / "m.json")])
    assert res.exit_code == 0, res.output
    smap = SlipMap.load(tmp_path / "m.json")
    assert list(smap.patches) == ["short_grass"]
    w = np.array([[2.0, 5.0], [4.0, 4.0]])
    pred = smap.predict(["short_grass"] * 2, w)
    np.testing.assert_allclose(pred[:, 0], beta(w[:, 0]), atol=2e-3)
    np.testing.assert_allclose(pred[:, 1], beta(w[:, 1]), atol=2e-3)
    np.testing.assert_allclose(pred[:, 2], np.arctan(0.02), atol=2e-3)
    res = CliRunner().invoke(app, ["slipmap", "merge", str(tmp_path / "m.json"), str(tmp_path / "m.json"),
                                   "--out", str(tmp_path / "g.json")])
    assert res.exit_code == 0, res.output
    np.testing.assert_allclose(SlipMap.load(tmp_path / "g.json").coef("short_grass"),
                               smap.coef("short_grass"), atol=1e-9)
