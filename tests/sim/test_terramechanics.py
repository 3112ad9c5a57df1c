"""Terramechanics curves (design §6.1-6.2): hand-worked values and the physical rules of §10."""

import math

import numpy as np
import pytest

from terrainml.classes import TERRAIN_CLASSES
from terrainml.lookup import terramechanics as tm
from terrainml.robot import load_robot

ROBOT = load_robot()
W = ROBOT.static_wheel_loads_n()[0]
S = np.linspace(0.0, 0.8, 1601)

# design §6.1 calibration targets (root of mu_net = 0 at the reference load)
TARGETS = {
    "pavement": (-0.01, 0.01), "compacted_dirt": (0.02, 0.05), "short_grass": (0.116, 0.135),
    "gravel_on_firm_soil": (0.122, 0.146), "tall_damp_grass": (0.16, 0.22), "tilled_loam": (0.17, 0.23),
    "dry_sand": (0.26, 0.34), "wet_mud": (0.35, 0.5),
}


def test_reference_load_is_equal_split():
    assert W == pytest.approx(80 * 9.81 / 3, rel=1e-6)


def test_burckhardt_dry_concrete_by_hand():
    p = tm.nominal_params("pavement")
    s = 0.1
    mu = 1.1973 * (1 - math.exp(-25.168 * s)) - 0.5373 * s
    assert float(tm.gross_thrust_n(p, W, s, ROBOT)) == pytest.approx(mu * W, rel=1e-9)
    # braking by symmetry
    assert float(tm.gross_thrust_n(p, W, -s, ROBOT)) == pytest.approx(-mu * W, rel=1e-9)
    # peak at ln(c1 c2 / c3) / c2 = 0.16 (design §6.2)
    mu_net = tm.net_traction_coefficient(p, W, S, ROBOT)
    assert S[np.argmax(mu_net)] == pytest.approx(0.16, abs=0.002)
    assert float(tm.motion_resistance_n(p, W, 0.0, ROBOT)) == pytest.approx(0.012 * W)


def test_bekker_static_sinkage_by_hand():
    p = tm.nominal_params("tilled_loam")
    k = 74.6e3 + 0.09 * 2080e3
    z0 = (3 * W / ((3 - 1.1) * k * math.sqrt(2 * 0.165))) ** (2 / (2 * 1.1 + 1))
    assert float(tm.static_sinkage_m(p, W, ROBOT)) == pytest.approx(z0, rel=1e-9)
    rc = k * z0 ** 2.1 / 2.1
    assert float(tm.motion_resistance_n(p, W, 0.0, ROBOT)) == pytest.approx(rc, rel=1e-9)


@pytest.mark.parametrize("name", TERRAIN_CLASSES)
def test_steady_slip_in_target(name):
    lo, hi = TARGETS[name]
    s = tm.steady_slip(tm.nominal_params(name), W, ROBOT)
    assert lo <= s <= hi


def test_steady_slip_non_decreasing_with_class_id():
    ss = [tm.steady_slip(tm.nominal_params(c), W, ROBOT) for c in range(8)]
    assert all(b >= a - 1e-9 for a, b in zip(ss, ss[1:]))


@pytest.mark.parametrize("name", TERRAIN_CLASSES)
def test_lookup_rules_hold(name):
    """design §10: s_T >= s_S + 0.03, no target beyond 0.6, |braking| > traction magnitude."""
    p = tm.nominal_params(name)
    mu = tm.net_traction_coefficient(p, W, S, ROBOT)
    i = int(np.argmax(mu))
    s_t = S[i] if i < len(S) - 1 else S[np.argmax(mu >= 0.9 * mu[i])]
    assert s_t >= tm.steady_slip(p, W, ROBOT) + 0.03
    assert s_t <= 0.6
    mb = -tm.net_traction_coefficient(p, W, -S, ROBOT)
    j = int(np.argmax(mb))
    s_b = S[j] if j < len(S) - 1 else S[np.argmax(mb >= 0.9 * mb[j])]
    assert s_b <= 0.6
    assert mb.max() > mu.max()
    if name in ("pavement", "compacted_dirt"):
        assert 0.10 <= s_t <= 0.20
    if name in ("tilled_loam", "dry_sand", "wet_mud"):      # thesis §8.3.2: braking target larger
        assert s_b >= s_t


def test_vectorised_and_shapes():
    p = tm.nominal_params("dry_sand")
    s = np.linspace(-1, 1, 11)
    out = tm.net_traction_coefficient(p, W, s, ROBOT)
    assert out.shape == (11,)
    assert np.all(tm.motion_resistance_n(p, W, s, ROBOT) >= 0)
    grid = tm.gross_thrust_n(p, np.array([[100.0], [200.0]]), s[None, :], ROBOT)
    assert grid.shape == (2, 11)
    # thrust odd in slip
    np.testing.assert_allclose(tm.gross_thrust_n(p, W, s, ROBOT), -tm.gross_thrust_n(p, W, -s, ROBOT))


def test_lateral_force_opposes_and_saturates():
    p = tm.nominal_params("short_grass")
    f = tm.lateral_force_n(p, W, np.array([-1.0, -0.01, 0.0, 0.01, 1.0]), ROBOT)
    assert f[2] == 0 and f[3] < 0 < f[1]
    assert abs(f[-1]) == pytest.approx(p.lateral_mu * W, rel=1e-3)


def test_sample_params_spread_and_determinism():
    a = tm.sample_params(2, np.random.default_rng(3))
    b = tm.sample_params(2, np.random.default_rng(3))
    c = tm.sample_params(2, np.random.default_rng(4))
    nom = tm.nominal_params(2)
    assert a == b and a != c
    assert 0.85 * nom.cohesion_pa <= a.cohesion_pa <= 1.15 * nom.cohesion_pa
    assert tm.sample_params(2, np.random.default_rng(3), spread=0.0) == nom
    with pytest.raises(ValueError):
        tm.sample_params(2, np.random.default_rng(0), spread=1.5)
