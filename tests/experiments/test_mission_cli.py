"""`terrainml mission list|run|plot` end to end (quick: two short missions)."""

from __future__ import annotations

import json

from typer.testing import CliRunner

from terrainml.cli import app

runner = CliRunner()


def test_list_names_the_suites():
    r = runner.invoke(app, ["mission", "list", "--json"])
    assert r.exit_code == 0, r.output
    counts = json.loads(r.stdout)
    assert set(counts) == {"greenhouse", "field"} and counts["field"]["seeds"] == "eval"
    r = runner.invoke(app, ["mission", "list"])
    assert r.exit_code == 0 and "greenhouse" in r.stdout and "field" in r.stdout


def test_run_limit_2_and_plot(tmp_path):
    out = tmp_path / "none.json"
    r = runner.invoke(app, ["mission", "run", "--suite", "field", "--policy", "none", "--limit", "2",
                            "--n-jobs", "2", "--traces", "--out", str(out)])
    assert r.exit_code == 0, r.output
    rep = json.loads(out.read_text())
    assert len(rep["missions"]) == 2 and rep["summary"]["overall"]["n"] == 2
    row = rep["missions"][0]
    for k in ("terrain", "success", "time_s", "distance_m", "energy_j_per_m", "spin_share",
              "max_sinkage_m", "demand_ratio", "family", "seed", "parameters"):
        assert k in row
    assert (tmp_path / rep["traces"]).is_file()
    figs = tmp_path / "figs"
    r = runner.invoke(app, ["mission", "plot", str(out), "--out", str(figs)])
    assert r.exit_code == 0, r.output
    pngs = sorted(p.name for p in figs.glob("*.png"))
    assert "policies.png" in pngs and len(pngs) == 3


def test_run_refusals(tmp_path):
    out = str(tmp_path / "r.json")
    for args, needle in ((["--suite", "orchard", "--policy", "none"], "suite"),
                         (["--suite", "field", "--policy", "magic"], "--policy"),
                         (["--suite", "field", "--policy", "terrain-aware"], "--model"),
                         (["--suite", "field", "--policy", "terrain-aware-closed"], "--model"),
                         (["--suite", "field", "--policy", "none", "--held-out", "snow"], "--held-out"),
                         (["--suite", "field", "--policy", "none", "--seeds", "test"], "--seeds")):
        r = runner.invoke(app, ["mission", "run", *args, "--out", out])
        assert r.exit_code == 2 and needle in r.output, r.output


def test_run_held_out_keeps_the_missions_on_that_class(tmp_path):
    out = tmp_path / "none.json"
    r = runner.invoke(app, ["mission", "run", "--suite", "greenhouse", "--held-out", "wet_mud", "--policy",
                            "none", "--limit", "2", "--out", str(out)])
    assert r.exit_code == 0, r.output
    rep = json.loads(out.read_text())
    assert rep["held_out"] == "wet_mud" and len(rep["missions"]) == 2
    for row in rep["missions"]:   # a wet-mud floor, or a dry-sand floor with wet-mud patches
        assert row["family"] == "greenhouse"
        assert row["terrain"] == "wet_mud" or any(p[2] == "wet_mud" for p in row["patches"])
