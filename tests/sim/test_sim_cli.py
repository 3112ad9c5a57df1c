"""`terrainml sim` command line: the contract other tools call."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

import terrainml.sim.generate as sim_generate
from terrainml.cli import app
from terrainml.io.ingest import load_run
from terrainml.schema import read_run_parquet

from cli_refusal import assert_refused

runner = CliRunner()


def test_generate_one_run_and_ingest(tmp_path):
    out = tmp_path / "grass.mcap"
    r = runner.invoke(app, ["sim", "generate", "--terrain", "short_grass", "--scenario", "straight",
                            "--speed-mps", "1.0", "--duration-s", "4", "--seed", "3", "--out", str(out)])
    assert r.exit_code == 0, r.output
    res = load_run(out)
    assert res.report.usable
    t = res.table
    assert (t["terrain"] == 2).all() and len(t) >= 399
    assert {"gt_slip1", "gt_state3", "gt_vx_mps", "cam_vx_mps"} <= set(t.columns)
    assert t["gt_vx_mps"].max() > 0.8


def test_generate_parquet_table(tmp_path):
    out = tmp_path / "sand.parquet"
    r = runner.invoke(app, ["sim", "generate", "--terrain", "dry_sand", "--scenario", "arc", "--duration-s", "3",
                            "--seed", "1", "--out", str(out)])
    assert r.exit_code == 0, r.output
    df = read_run_parquet(out)
    assert (df["terrain"] == 6).all() and df["run_id"].iloc[0] == "sand"
    assert np.isfinite(df["gt_slip2"]).all()


def test_generate_dataset_index(tmp_path):
    out = tmp_path / "ds"
    r = runner.invoke(app, ["sim", "generate", "--runs-per-class", "1", "--seed", "0", "--out", str(out),
                            "--duration-s", "2", "--format", "parquet", "--n-jobs", "1"])
    assert r.exit_code == 0, r.output
    rows = list(csv.DictReader((out / "index.csv").open()))
    assert [k for k in rows[0]] == ["run_id", "file", "terrain", "scenario", "seed", "duration_s"]
    assert len(rows) == 8 and len({row["scenario"] for row in rows}) >= 4
    assert all((out / row["file"]).is_file() for row in rows)
    assert {row["terrain"] for row in rows} == {"pavement", "compacted_dirt", "short_grass", "gravel_on_firm_soil",
                                              "tall_damp_grass", "tilled_loam", "dry_sand", "wet_mud"}


def test_bad_input_exit_2(tmp_path):
    r = runner.invoke(app, ["sim", "generate", "--terrain", "lava", "--out", str(tmp_path / "x.mcap")])
    assert r.exit_code == 2 and "lava" in r.output
    r = runner.invoke(app, ["sim", "generate", "--terrain", "pavement", "--scenario", "loop",
                            "--out", str(tmp_path / "x.mcap")])
    assert r.exit_code == 2 and "loop" in r.output
    r = runner.invoke(app, ["sim", "generate", "--terrain", "pavement", "--out", str(tmp_path / "x.txt")])
    assert r.exit_code == 2
    r = runner.invoke(app, ["sim", "plot", str(tmp_path / "missing.mcap"), "--out", str(tmp_path)])
    assert r.exit_code == 2 and "missing.mcap" in r.output


def test_plot_writes_pngs(tmp_path):
    out = tmp_path / "g.mcap"
    assert runner.invoke(app, ["sim", "generate", "--terrain", "gravel_on_firm_soil", "--duration-s", "3",
                               "--out", str(out)]).exit_code == 0
    r = runner.invoke(app, ["sim", "plot", str(out), "--out", str(tmp_path / "plots")])
    assert r.exit_code == 0, r.output
    assert (tmp_path / "plots" / "g_slip.png").stat().st_size > 10_000


@pytest.fixture
def no_simulation(monkeypatch):
    """Make any simulation fail the test: refusals must come before the long work."""
    def boom(*args, **kwargs):
        raise AssertionError("simulated although the command should have refused first")

    for name in ("simulate", "generate_dataset", "write_run"):
        monkeypatch.setattr(sim_generate, name, boom)


@pytest.mark.parametrize("n_jobs", ["0", "-2"])
def test_bad_n_jobs_refused_before_simulating(tmp_path, no_simulation, n_jobs):
    out = tmp_path / "ds"
    r = runner.invoke(app, ["sim", "generate", "--runs-per-class", "1", "--n-jobs", n_jobs, "--out", str(out)])
    assert_refused(r, "--n-jobs", f"got {n_jobs}")
    assert not out.exists()


def test_unwritable_output_refused_before_simulating(tmp_path, no_simulation):
    blocker = tmp_path / "blocker"
    blocker.write_text("a file, not a folder")  # root ignores permission bits, not this
    one = blocker / "run.mcap"
    assert_refused(runner.invoke(app, ["sim", "generate", "--terrain", "pavement", "--out", str(one)]), one)
    ds = blocker / "ds"
    assert_refused(runner.invoke(app, ["sim", "generate", "--runs-per-class", "1", "--out", str(ds)]), ds)
    assert_refused(runner.invoke(app, ["sim", "generate", "--runs-per-class", "1", "--out", str(blocker)]),
             blocker, "not a folder")
    if Path("/proc/self").is_dir():
        assert_refused(runner.invoke(app, ["sim", "generate", "--terrain", "pavement", "--out", "/proc/run.mcap"]),
                 "/proc/run.mcap")
