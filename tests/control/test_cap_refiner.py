"""Online cap refinement (design §12): hand-worked estimator cases and the acceptance
test on the simulator's truth (tuning seeds >= 5000 only; the mission suite's evaluation seeds are
never used for tuning)."""

from __future__ import annotations

import numpy as np
import pytest

from terrainml.control.cap_refiner import (CapRefiner, CapRefinerConfig, peak_from_rise,
                                           rise_crossing_slip, thrust_peak_offset)

CFG = CapRefinerConfig()


def _ramp(s):
    """Thrust 0 below slip 0.2, rising linearly to 100 N at 0.3, flat above: the 50 % crossing
    is 0.25 exactly."""
    return 100.0 * np.clip((np.asarray(s) - 0.2) / 0.1, 0.0, 1.0)


def test_rise_crossing_of_a_linear_ramp():
    s = np.linspace(0.0, 0.6, 601)
    lv = np.array([0.3, 0.5, 0.9])
    np.testing.assert_allclose(rise_crossing_slip(s, _ramp(s), lv), [0.23, 0.25, 0.29], atol=1e-9)
    # scale-free: a wheel with twice the load (twice the thrust) has the same crossings
    np.testing.assert_allclose(rise_crossing_slip(s, 2 * _ramp(s), lv), [0.23, 0.25, 0.29],
                               atol=1e-9)
    assert np.isnan(rise_crossing_slip(s, 0 * s, lv)).all()                 # no rise at all


def _bins(lo, hi, width=0.02, weight=10.0, shift=0.0):
    """Exact bins of the ramp shifted by ``shift`` over [lo, hi): mean slip, mean thrust, weight."""
    x = np.arange(lo, hi, width) + width / 2
    return x, _ramp(x + shift), np.full_like(x, weight)


def test_peak_needs_a_bin_on_the_rise_below_a_plateau():
    off = thrust_peak_offset(np.linspace(0, 0.99, 991), _ramp(np.linspace(0, 0.99, 991)), 0.42)
    x, y, w = _bins(0.02, 0.4)
    assert peak_from_rise(x, y, w, off, CFG) == pytest.approx(0.42, abs=1e-6)
    assert peak_from_rise(*_bins(0.02, 0.27), off, CFG) is None     # data end on the rise
    assert peak_from_rise(x[:1], y[:1], w[:1], off, CFG) is None    # too few bins
    holey = np.where((x > 0.2) & (x < 0.3), 0.0, w)                 # no bin on the rise
    assert peak_from_rise(x, y, holey, off, CFG) is None
    assert peak_from_rise(x, y, w, np.full_like(off, np.nan), CFG) is None   # no nominal curve


def test_offset_is_the_crossing_minus_the_net_peak():
    """Nominal ramp with the net peak at 0.42: the offset at level r is 0.2 + 0.1 r - 0.42."""
    s = np.linspace(0, 0.99, 991)
    np.testing.assert_allclose(thrust_peak_offset(s, _ramp(s), 0.42),
                               0.2 + 0.1 * CFG.levels - 0.42, atol=1e-3)
    assert np.isnan(thrust_peak_offset(s, 0 * s, 0.42)).all()               # no rise


def test_refiner_moves_the_cap_by_the_measured_shift_within_the_band():
    """Samples of the ramp shifted by -0.05 (the rise at 0.15-0.25) against a nominal rise at
    0.2-0.3 (net peak 0.42): before any data the class target; after enough travel the cap moves
    (rate-limited) to 0.42 - 0.05 = 0.37, and never beyond s_T +- band."""
    ref = CapRefiner(1, CapRefinerConfig(max_cap_rate_per_m=1.0))
    s_nom = np.linspace(0, 0.99, 991)
    off = thrust_peak_offset(s_nom, _ramp(s_nom), 0.42)
    assert ref.cap([0.42], off)[0] == pytest.approx(0.42)
    for s in np.tile(np.arange(0.1, 0.45, 0.005), 10):
        ref.update([s], [_ramp(s + 0.05) + 1.0], [0.01], 0.01)
        ref.update([s], [_ramp(s + 0.05) + 1.0], [0.01], 0.01)   # slow slip: the gate passes
    for _ in range(10):
        cap = ref.cap([0.42], off)
        ref.update([np.nan], [np.nan], [1.0], 0.01)                   # 1 m of travel per call
    assert cap[0] == pytest.approx(0.37, abs=0.005)
    assert ref.cap([0.42], off - 0.3)[0] == pytest.approx(0.52)      # clipped at s_T + band
    assert ref.cap([0.42], np.nan)[0] == 0.42                        # no nominal curve: unrefined


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


# Tuning draws (the estimator's constants were chosen on these only) and held-out draws (never
# looked at before the estimator was fixed). Limiter: the mission policies' settings
# (baselines.mission_limiter_config, build-up gain 6.0). Measured after 10 m of traction, cap - true
# peak per wheel, * = no confirmed estimate (class target 0.421 served): 5003 +0.015/+0.002/+0.016,
# 5006 +0.003/-0.022/+0.000, 5027 -0.019*/-0.012/+0.010; held out: 7101 +0.009*/+0.009*/-0.003,
# 7102 +0.003*/+0.003*/+0.008, 7103 +0.009/-0.005/+0.014, 7104 -0.014*/-0.014*/+0.017,
# 7105 +0.009/-0.006/+0.010, 7106 +0.005/+0.010*/+0.008. Unconfirmed wheels saw no flat top below
# the cap (a draw peaking near or above nominal): the documented "rise not finished" case.
TUNING_SEEDS = [5003, 5006, 5027]      # draw peaks 0.364, 0.393, 0.440 vs 0.421 nominal
HELD_OUT_SEEDS = [7101, 7102, 7103, 7104, 7105, 7106]   # peaks 0.405-0.435


@pytest.mark.acceptance
@pytest.mark.parametrize("seed", TUNING_SEEDS + HELD_OUT_SEEDS)
def test_cap_lands_within_003_of_the_true_peak_after_10_m(seed):
    cap, peak, travel = _refined_cap_after_traction(seed)
    assert travel.min() >= 10.0
    np.testing.assert_allclose(cap, peak, atol=0.03)
