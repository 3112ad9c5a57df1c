"""Cheap simulator-based checks (the full 8 classes x 3 seeds acceptance is in
benchmarks/bench_estimation.py). Skipped when the simulator is not importable."""

import numpy as np
import pytest

from terrainml import sim
from terrainml.estimation.consistency import consistency_report, truth_metrics
from terrainml.estimation.dynamic_state import classify_states
from terrainml.estimation.run import estimate_run_detailed
from terrainml.sim import output, truth


@pytest.fixture(scope="module")
def mud_run():
    # wet mud (class 7): true steady slip ~0.4, the hardest case for zero-slip wheel rows
    res = sim.Simulator(sim.make_scenario("straight", "wet_mud", duration_s=12.0), seed=3).run()
    return output.run_table(res, run_id="mud")


def test_robust_slip_and_velocity_against_simulator_truth(mud_run):
    out = {}
    for preset in ("thesis", "robust"):
        est, diag = estimate_run_detailed(mud_run, preset=preset)
        out[preset] = (truth_metrics(est, 3), consistency_report(est, diag))
    rob, the = out["robust"][0], out["thesis"][0]
    assert rob["steady_slip_mae"] <= 0.01
    assert rob["vel_rmse_mps"] <= 0.02
    assert the["steady_slip_mae"] >= 2 * rob["steady_slip_mae"]
    assert out["robust"][1]["median_nis_per_dof"] < 5  # no divergence


def test_state_machine_matches_simulator_truth_definition():
    # same definition (hysteresis theta/2, 0.2 s debounce) as the simulator's truth labels
    rng = np.random.default_rng(0)
    t = np.arange(3000) * 0.01
    v = np.clip(np.cumsum(rng.normal(0, 0.01, (3000, 3)), axis=0) + 0.1, -1, 1)  # crosses idle
    p = np.convolve(rng.normal(0, 0.15, 3000), np.ones(15) / 15, "same")[:, None] + rng.normal(0, 0.005, (3000, 3))
    ours = classify_states(t, p, v)
    ref = truth.wheel_states(t, p, v)
    assert len(np.unique(ref)) == 4  # all four states exercised
    np.testing.assert_array_equal(ours, ref)
