"""Slip formula (thesis Table 8.1, dead band, saturation) and the dynamic-state machine."""

import numpy as np
import pytest

from terrainml.estimation.dynamic_state import (BRAKING, IDLE, STEADY, TRACTION, WheelStateMachine,
                                                classify_states, wheel_power)
from terrainml.estimation.slip import slip_ratio, wheel_v_long

# thesis Table 8.1: case, v_long [m/s], omega r [m/s], slip (3 decimals), r = 1 m
TABLE_8_1 = [
    ("1A", +0.6, +0.70, +0.143),
    ("1B", +0.6, +0.63, +0.048),
    ("1C", +0.5, +0.47, -0.060),
    ("1D", +0.5, +0.39, -0.220),
    ("2A", -0.6, -0.70, -0.143),
    ("2B", -0.6, -0.63, -0.048),
    ("2C", -0.5, -0.47, +0.060),
    ("2D", -0.5, -0.39, +0.220),
]


@pytest.mark.parametrize("case,v_long,v_ang,expected", TABLE_8_1)
def test_slip_reproduces_thesis_table_8_1(case, v_long, v_ang, expected):
    assert round(slip_ratio(v_ang, v_long), 3) == pytest.approx(expected, abs=1e-12), case


def test_slip_vectorised_equals_scalar():
    v_long = np.array([c[1] for c in TABLE_8_1])
    v_ang = np.array([c[2] for c in TABLE_8_1])
    vec = slip_ratio(v_ang, v_long)
    assert np.round(vec, 3) == pytest.approx([c[3] for c in TABLE_8_1])
    assert vec == pytest.approx([slip_ratio(a, b) for a, b in zip(v_ang, v_long)])


def test_dead_band_and_saturation():
    # both speeds below 0.05 m/s: forced to 0 (thesis §7.2.1)
    assert slip_ratio(0.04, 0.01) == 0.0
    assert slip_ratio(-0.049, 0.049) == 0.0
    # one speed above the dead band: computed (0.06 - 0.01) / 0.06
    assert slip_ratio(0.06, 0.01) == pytest.approx(0.05 / 0.06)
    # spinning in place: wheel turns, body still -> +1 (eq. 7.1)
    assert slip_ratio(0.5, 0.0) == 1.0
    # locked wheel sliding forward -> -1 (eq. 7.2)
    assert slip_ratio(0.0, 0.5) == -1.0
    # opposite signs would give |s| = 2: saturated to +-1
    assert slip_ratio(1.0, -1.0) == 1.0
    assert slip_ratio(-1.0, 1.0) == -1.0
    assert np.isnan(slip_ratio(np.nan, 1.0))


def test_wheel_v_long_lever_arm_and_steering():
    # pure yaw at 1 rad/s: wheel at (x=0, y=-0.756) moves forward at 0.756 m/s
    v = wheel_v_long(0.0, 0.0, 1.0, np.array([0.0, np.pi / 2]), np.array([0.0, 0.5]), np.array([-0.756, 0.0]))
    assert v == pytest.approx([0.756, 0.5])


def _profile(dt=0.01):
    """Accelerate 1 m/s^2 for 1 s, cruise 1 m/s, brake at -1 m/s^2, rest.

    Hand-worked truth for theta = 0.02, idle 0.05 m/s, dwell 0.2 s (debounce): raw traction from
    t = 1.05 s (v > 0.05) is taken at 1.25 s; steady from 2.0 s is taken at 2.2 s; braking from
    5.0 s at 5.2 s; idle (v < 0.05 at 5.95 s) at 6.15 s. Labels keep 0.05 s away from the edges.
    """
    t = np.arange(0, 8, dt)
    v = np.clip(t - 1.0, 0, 1) - np.clip(t - 5.0, 0, 1)
    a = np.gradient(v, dt)
    truth = np.full(t.shape, "", dtype=object)
    truth[(t > 1.30) & (t < 2.15)] = "traction"
    truth[(t > 2.25) & (t < 5.15)] = "steady"
    truth[(t > 5.25) & (t < 6.10)] = "braking"
    truth[(t < 1.2) | (t > 6.2)] = "idle"
    return t, v, a, truth


def test_state_machine_hand_profile_agreement_and_dwell():
    t, v, a, truth = _profile()
    wx, wy = np.array([-0.5, 0.5]), np.array([0.0, 0.0])
    v_long = np.column_stack([v, v])
    power = wheel_power(a, np.zeros_like(a), np.zeros_like(a), np.zeros((len(t), 2)), v_long, wx, wy)
    codes = classify_states(t, power, v_long)
    names = np.array(["idle", "steady", "traction", "braking"], dtype=object)[codes[:, 0]]
    for state in ("traction", "braking", "steady", "idle"):
        m = truth == state
        assert (names[m] == state).all(), state
    # no state segment (other than the first and last) shorter than the 0.2 s dwell
    change = np.flatnonzero(names[1:] != names[:-1]) + 1
    assert np.diff(t[change]).min() >= 0.2 - 1e-9


def test_hysteresis_and_dwell_suppress_chatter():
    sm = WheelStateMachine(1, theta=0.02, dwell_s=0.2)
    sm.step(0.0, np.array([0.0]), np.array([1.0]))  # steady
    states = []
    # power oscillating around theta every tick: dwell prevents chatter
    for k in range(1, 100):
        p = 0.03 if k % 2 else 0.0
        states.append(int(sm.step(k * 0.01, np.array([p]), np.array([1.0]))[0]))
    changes = np.flatnonzero(np.diff(states)) + 1
    assert len(changes) <= 99 * 0.01 / 0.2 + 1
    # hysteresis: once in traction, Power between theta/2 and theta keeps traction
    sm = WheelStateMachine(1, theta=0.02, dwell_s=0.0)
    sm.step(0.0, np.array([0.05]), np.array([1.0]))
    assert sm.state[0] == TRACTION
    assert sm.step(0.01, np.array([0.015]), np.array([1.0]))[0] == TRACTION
    assert sm.step(0.02, np.array([0.005]), np.array([1.0]))[0] == STEADY
    assert sm.step(0.03, np.array([-0.05]), np.array([1.0]))[0] == BRAKING
    assert sm.step(0.04, np.array([0.0]), np.array([0.01]))[0] == IDLE


def test_steady_arc_is_steady():
    # constant-speed arc: inertial acceleration is centripetal, wheel power ~ 0
    vx, r = 1.0, 0.5
    wx, wy = np.array([-0.5075, 0.5075, 0.0]), np.array([0.0, 0.0, -0.756])
    u, w = vx - r * wy, r * wx
    d = np.arctan2(w, u)
    v_long = u * np.cos(d) + w * np.sin(d)
    power = wheel_power(np.array(0.0), np.array(r * vx), np.array(r), d, v_long, wx, wy)
    assert np.abs(power).max() < 1e-9
