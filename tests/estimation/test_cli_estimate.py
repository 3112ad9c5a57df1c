"""`terrainml estimate` on a canonical Parquet run with truth; bad input gives exit code 2."""

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

import terrainml.estimation.run as est_run
from terrainml.cli import app
from terrainml.testing import kinematic_run
from terrainml.schema import write_run_parquet

from cli_refusal import assert_refused

runner = CliRunner()


def test_estimate_writes_est_report_and_plots(tmp_path):
    run = kinematic_run(duration_s=8.0, slip=0.25, seed=9)
    src = write_run_parquet(run, tmp_path / "run.parquet")
    out = tmp_path / "est.parquet"
    res = runner.invoke(app, ["estimate", str(src), "--out", str(out), "--preset", "robust",
                              "--plot", str(tmp_path / "plots")])
    assert res.exit_code == 0, res.output
    est = pd.read_parquet(out)
    assert {"slip1", "state3", "nis", "estimator_ok", "gt_slip1"} <= set(est.columns)
    rep = json.loads((tmp_path / "est.report.json").read_text())
    assert rep["truth"]["vel_rmse_mps"] < 0.02
    assert 0 <= rep["consistency"]["frac_in_95_band"] <= 1
    # the run has 0.25 true slip from t = 0: steady slip error is small against truth
    steady = est.t_s > 3
    err = np.abs(est.loc[steady, "slip1"] - est.loc[steady, "gt_slip1"]).mean()
    assert err < 0.01
    assert len(list((tmp_path / "plots").glob("*.png"))) >= 6


def test_estimate_bad_inputs_exit_2(tmp_path):
    res = runner.invoke(app, ["estimate", str(tmp_path / "missing.parquet"), "--out", str(tmp_path / "e.parquet")])
    assert res.exit_code == 2
    assert "missing.parquet" in res.output.replace("\n", "")
    run = kinematic_run(duration_s=1.0)
    src = write_run_parquet(run, tmp_path / "run.parquet")
    res = runner.invoke(app, ["estimate", str(src), "--out", str(tmp_path / "e.parquet"), "--preset", "nope"])
    assert res.exit_code == 2 and "preset" in res.output
    # wheel count of the table does not match the robot
    res = runner.invoke(app, ["estimate", str(src), "--out", str(tmp_path / "e.parquet"), "--robot", "husky"])
    assert res.exit_code == 2 and "wheel" in res.output
    bad = tmp_path / "bad.parquet"
    bad.write_text("not parquet")
    res = runner.invoke(app, ["estimate", str(bad), "--out", str(tmp_path / "e.parquet")])
    assert res.exit_code == 2 and "bad.parquet" in res.output.replace("\n", "")


@pytest.fixture
def no_estimation(monkeypatch):
    """Make the estimation fail the test: refusals must come before the long work."""
    def boom(*args, **kwargs):
        raise AssertionError("estimated although the command should have refused first")

    monkeypatch.setattr(est_run, "estimate_run_detailed", boom)


def test_unwritable_outputs_refused_before_estimating(tmp_path, no_estimation):
    src = write_run_parquet(kinematic_run(duration_s=1.0), tmp_path / "run.parquet")
    blocker = tmp_path / "blocker"
    blocker.write_text("a file, not a folder")  # root ignores permission bits, not this
    out = blocker / "est.parquet"
    assert_refused(runner.invoke(app, ["estimate", str(src), "--out", str(out)]), out)
    plots = blocker / "plots"
    assert_refused(runner.invoke(app, ["estimate", str(src), "--out", str(tmp_path / "e.parquet"),
                                 "--plot", str(plots)]), plots)
    # the report goes next to the EST table: a folder in its place is refused too
    (tmp_path / "e.report.json").mkdir()
    assert_refused(runner.invoke(app, ["estimate", str(src), "--out", str(tmp_path / "e.parquet")]),
             tmp_path / "e.report.json")
    if Path("/proc/self").is_dir():
        assert_refused(runner.invoke(app, ["estimate", str(src), "--out", "/proc/est.parquet"]), "/proc/est.parquet")
    assert not (tmp_path / "e.parquet").exists()


def test_wheel_count_mismatch_refused_before_estimating(tmp_path, no_estimation):
    src = write_run_parquet(kinematic_run(duration_s=1.0), tmp_path / "run.parquet")  # 3 wheels
    res = runner.invoke(app, ["estimate", str(src), "--out", str(tmp_path / "e.parquet"), "--robot", "husky"])
    assert_refused(res, src, "3 wheel", "'husky' has 4")
