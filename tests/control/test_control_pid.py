"""Per-wheel slip PID (SYSTEM §12) against thesis Table 8.1 and simple closed-loop behaviour."""

from __future__ import annotations

import math

import numpy as np
import pytest

from terrainml.control.pid import SlipPID, SlipPIDConfig
from terrainml.estimation.slip import slip_ratio
from terrainml.lookup.policy import desired_slip_per_wheel

# Thesis Table 8.1 ("Summary analysis of traction control operational cases"), transcribed by
# hand from the thesis text. Kp = 1, Ki = Kd = 0, r = 1 m, s_T = 0.1, s_B = -0.15.
# case, direction, manoeuvre, v_long [m/s], omega r [m/s], slip, desired, error, PID, omega_ODrive
TABLE_8_1 = [
    ("1A", "Forward", "traction", +0.6, +0.70, +0.143, +0.10, -0.043, -0.043, +0.657),
    ("1B", "Forward", "traction", +0.6, +0.63, +0.048, +0.10, +0.052, +0.052, +0.682),
    ("1C", "Forward", "braking", +0.5, +0.47, -0.060, -0.15, -0.090, -0.090, +0.380),
    ("1D", "Forward", "braking", +0.5, +0.39, -0.220, -0.15, +0.070, +0.070, +0.460),
    ("2A", "Backward", "traction", -0.6, -0.70, -0.143, -0.10, +0.043, +0.043, -0.657),
    ("2B", "Backward", "traction", -0.6, -0.63, -0.048, -0.10, -0.052, -0.052, -0.682),
    ("2C", "Backward", "braking", -0.5, -0.47, +0.060, +0.15, +0.090, +0.090, -0.380),
    ("2D", "Backward", "braking", -0.5, -0.39, +0.220, +0.15, -0.070, -0.070, -0.460),
]
R_M = 1.0


class ThesisTargets:
    """The thesis's manual targets of §8.3.2 (s_T = 0.1, s_B = -0.15)."""

    def target(self, class_id: int, state: str) -> float:
        return {"traction": 0.1, "braking": -0.15, "steady": 0.0, "idle": 0.0}[state]


def r3(x: float) -> float:
    return round(float(x), 3) + 0.0  # + 0.0 turns -0.0 into 0.0


@pytest.mark.parametrize("row", TABLE_8_1, ids=[r[0] for r in TABLE_8_1])
def test_thesis_table_8_1_case(row):
    case, _dir, state, v_long, omega_r, slip_t, des_t, err_t, pid_t, odrive_t = row
    omega_radps = omega_r / R_M
    slip = slip_ratio(omega_radps * R_M, v_long)
    s_des = desired_slip_per_wheel(0, [state], [v_long], ThesisTargets())[0]
    pid = SlipPID(1, SlipPIDConfig(kp=1.0, ki=0.0, kd=0.0))
    out = pid.step([s_des], [slip], v_long_mps=[v_long], body_speed_mps=abs(v_long),
                   omega_low_level_radps=[omega_radps], dt_s=0.01)
    assert r3(slip) == pytest.approx(slip_t, abs=1e-12), f"{case} slip"
    assert r3(s_des) == pytest.approx(des_t, abs=1e-12), f"{case} desired"
    assert r3(out.error[0]) == pytest.approx(err_t, abs=1e-12), f"{case} error"
    assert r3(out.pid_out_radps[0]) == pytest.approx(pid_t, abs=1e-12), f"{case} PID"
    assert r3(out.omega_cmd_radps[0]) == pytest.approx(odrive_t, abs=1e-12), f"{case} ODrive"
    assert bool(out.enabled[0])


def test_thesis_table_8_1_all_cases_as_eight_wheels_at_once():
    """The vectorised controller gives the same table when the eight cases are eight wheels."""
    v = np.array([r[3] for r in TABLE_8_1])
    wr = np.array([r[4] for r in TABLE_8_1])
    states = [r[2] for r in TABLE_8_1]
    s_des = desired_slip_per_wheel(0, states, v, ThesisTargets())
    out = SlipPID(8).step(s_des, slip_ratio(wr, v), v, 0.55, wr / R_M, 0.01)
    np.testing.assert_allclose(np.round(out.omega_cmd_radps, 3), [r[9] for r in TABLE_8_1],
                               atol=1e-12)


def _step(pid, s_des, s_meas, v=1.0, body=1.0, omega=6.0, dt=0.01):
    return pid.step([s_des], [s_meas], [v], body, [omega], dt)


def test_disabled_below_wheel_speed_threshold_passes_low_level_command_through():
    pid = SlipPID(2, SlipPIDConfig(kp=2.0, ki=1.0))
    out = pid.step([0.2, 0.2], [0.0, 0.0], v_long_mps=[0.049, -0.049], body_speed_mps=1.0,
                   omega_low_level_radps=[3.0, -2.0], dt_s=0.01)
    assert not out.enabled.any()
    np.testing.assert_array_equal(out.pid_out_radps, 0.0)
    np.testing.assert_array_equal(out.error, 0.0)
    np.testing.assert_array_equal(out.omega_cmd_radps, [3.0, -2.0])


def test_disabled_when_body_is_slow_even_if_wheel_is_fast():
    pid = SlipPID(1)
    out = _step(pid, 0.2, 0.0, v=0.5, body=0.04)
    assert not out.enabled[0] and out.omega_cmd_radps[0] == 6.0
    out = _step(pid, 0.2, 0.0, v=0.5, body=0.05)  # threshold is inclusive (>= 0.05)
    assert out.enabled[0] and out.pid_out_radps[0] == pytest.approx(0.2)


def test_integrator_accumulates_is_clamped_and_resets_when_disabled():
    cfg = SlipPIDConfig(kp=0.0, ki=10.0, integral_limit_radps=0.5, output_limit_radps=5.0)
    pid = SlipPID(1, cfg)
    out = _step(pid, 0.1, 0.0)
    assert out.pid_out_radps[0] == pytest.approx(10.0 * 0.1 * 0.01)
    for _ in range(200):
        out = _step(pid, 0.1, 0.0)
    assert out.pid_out_radps[0] == pytest.approx(0.5)  # clamped integral
    _step(pid, 0.1, 0.0, v=0.0)  # wheel stops: disabled -> reset
    out = _step(pid, 0.1, 0.0)
    assert out.pid_out_radps[0] == pytest.approx(10.0 * 0.1 * 0.01)


def test_output_limited_and_no_windup_while_saturated():
    cfg = SlipPIDConfig(kp=100.0, ki=50.0, output_limit_radps=1.0, integral_limit_radps=10.0)
    pid = SlipPID(1, cfg)
    for _ in range(100):
        out = _step(pid, 0.5, 0.0)
    assert out.pid_out_radps[0] == pytest.approx(1.0)
    assert pid.integral_radps[0] < 0.1  # did not wind up to the 10 rad/s clamp
    out = _step(pid, 0.0, 0.0)  # error vanishes: output leaves saturation at once
    assert abs(out.pid_out_radps[0]) < 0.1


def test_derivative_acts_on_filtered_measurement_not_on_setpoint_steps():
    cfg = SlipPIDConfig(kp=0.0, kd=1.0, derivative_tau_s=0.05)
    pid = SlipPID(1, cfg)
    _step(pid, 0.1, 0.05)
    out = _step(pid, 0.4, 0.05)  # setpoint jumps, measurement constant: no kick
    assert out.pid_out_radps[0] == pytest.approx(0.0, abs=1e-12)
    out = _step(pid, 0.4, 0.15)  # measurement rises: derivative opposes it, smaller than raw
    raw = -1.0 * (0.15 - 0.05) / 0.01
    assert raw < out.pid_out_radps[0] < 0.0


def test_non_finite_inputs_never_produce_nan():
    pid = SlipPID(3, SlipPIDConfig(ki=1.0, kd=0.1))
    out = pid.step([0.1, np.nan, 0.1], [0.0, 0.0, np.inf], [1.0, 1.0, 1.0], 1.0,
                   [5.0, 5.0, 5.0], 0.01)
    assert np.all(np.isfinite(out.omega_cmd_radps))
    assert out.enabled.tolist() == [True, False, False]
    out = pid.step([0.1] * 3, [0.0] * 3, [1.0] * 3, math.nan, [5.0] * 3, 0.01)
    assert not out.enabled.any() and np.all(np.isfinite(out.omega_cmd_radps))


def test_bad_shapes_and_configs_are_rejected():
    with pytest.raises(ValueError, match="slip_desired"):
        SlipPID(3).step([0.1, 0.1], [0.0] * 3, [1.0] * 3, 1.0, [1.0] * 3, 0.01)
    with pytest.raises(ValueError, match="kp"):
        SlipPIDConfig(kp=-1.0)
    with pytest.raises(ValueError, match="output_limit"):
        SlipPIDConfig(output_limit_radps=0.0)


@pytest.mark.parametrize("v_mps,s_target", [(1.0, 0.15), (-1.0, -0.15), (1.0, -0.2),
                                            (-0.8, 0.2)])
def test_pi_loop_drives_a_wheel_to_the_desired_slip_in_both_directions(v_mps, s_target):
    """A wheel whose speed follows the command with a 40 ms lag (the ODrive velocity loop) at
    constant ground speed: the PI loop settles on the desired slip whatever the sign."""
    radius, dt, tau = 0.165, 0.01, 0.04
    omega_ll = v_mps / radius  # kinematic set-point: zero slip
    omega = omega_ll
    pid = SlipPID(1, SlipPIDConfig(kp=5.0, ki=20.0, output_limit_radps=10.0,
                                   integral_limit_radps=10.0))
    for _ in range(500):
        s = slip_ratio(omega * radius, v_mps)
        cmd = pid.step([s_target], [s], [v_mps], abs(v_mps), [omega_ll], dt).omega_cmd_radps[0]
        omega += (1.0 - math.exp(-dt / tau)) * (cmd - omega)
    assert slip_ratio(omega * radius, v_mps) == pytest.approx(s_target, abs=2e-3)
