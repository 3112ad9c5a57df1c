"""`terrainml control closed-loop`: the slip PID acting on the simulator (SYSTEM §12)."""

from __future__ import annotations

import json
import math

import pytest
from typer.testing import CliRunner

from terrainml.cli import app
from terrainml.control.closed_loop import run_closed_loop
from terrainml.control.pid import SlipPIDConfig

KEYS = ("energy_j_per_m", "mean_speed_mps", "mean_tractive_efficiency", "stuck_events")


def test_cli_report_has_the_contract_keys(tmp_path):
    out = tmp_path / "r.json"
    res = CliRunner().invoke(app, ["control", "closed-loop", "--terrain", "pavement", "--policy",
                                   "fixed", "--duration-s", "4", "--seed", "1", "--out", str(out)])
    assert res.exit_code == 0, res.output
    rep = json.loads(out.read_text())
    assert all(k in rep for k in KEYS)
    assert all(math.isfinite(rep[k]) for k in KEYS)
    bad = CliRunner().invoke(app, ["control", "closed-loop", "--terrain", "lava"])
    assert bad.exit_code == 2


def test_no_control_matches_the_plain_simulator():
    from terrainml.sim.generate import simulate

    rep = run_closed_loop("dry_sand", "none", duration_s=6.0, seed=3)
    plain = simulate(6, "straight", duration_s=6.0, seed=3)  # same scenario and seed, no controller
    assert rep["energy_j_per_m"] == pytest.approx(plain.energy_j / plain.distance_m, rel=1e-9)
    assert rep["stuck_events"] == plain.stuck_events


def test_fixed_low_target_holds_the_wheels_back_on_soft_soil():
    """Tilled loam needs about 0.2 slip to cruise: a PID pinned to 0.1 must slow the robot."""
    cfg = SlipPIDConfig(kp=20.0, ki=20.0)
    free = run_closed_loop("tilled_loam", "none", duration_s=10.0, seed=1, pid=cfg)
    fixed = run_closed_loop("tilled_loam", "fixed", duration_s=10.0, seed=1, pid=cfg)
    assert fixed["mean_speed_mps"] < 0.8 * free["mean_speed_mps"]


def test_terrain_aware_with_a_model_serves_through_the_predictor(model_dir):
    rep = run_closed_loop("pavement", "terrain-aware", model=model_dir, duration_s=4.0, seed=2)
    assert rep["classifier"] == "model"
    # no 2 s window can exist before t = 2 s: at least half of a 4 s run is start-up fallback
    assert rep["fallback_fraction"] >= 0.5
    assert all(math.isfinite(rep[k]) for k in KEYS)
