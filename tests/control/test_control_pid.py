"""Per-wheel slip PID (design §12) against thesis Table 8.1 and simple closed-loop behaviour."""

from __future__ import annotations

import math

import numpy as np
import pytest

from terrainml.control.pid import SlipPID, SlipPIDConfig
from terrainml.estimation.slip import slip_ratio
from terrainml.lookup.wheel_targets import desired_slip_per_wheel

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


# ---------------------------------------------------------------- feed-forward, limiter, slew
from terrainml.control.pid import wheel_speed_for_slip  # noqa: E402


@pytest.mark.parametrize("v_mps,s", [(1.0, 0.3), (1.0, -0.3), (-0.7, -0.2), (-0.7, 0.2),
                                     (0.5, 0.0)])
def test_feedforward_wheel_speed_inverts_the_slip_definition(v_mps, s):
    radius = 0.165
    omega = wheel_speed_for_slip(v_mps, s, radius)
    assert slip_ratio(float(omega) * radius, v_mps) == pytest.approx(s, abs=1e-12)


def test_feedforward_puts_the_command_on_the_target_slip_in_one_tick():
    """Zero gains: the command alone is the wheel speed of the target slip at the measured
    wheel-centre speed, whatever the low-level set-point was."""
    radius = 0.165
    cfg = SlipPIDConfig(kp=0.0, ki=0.0, wheel_radius_m=radius, output_limit_radps=50.0)
    pid = SlipPID(4, cfg)
    v = np.array([0.8, 0.8, -0.6, -0.6])
    s_des = np.array([0.25, -0.3, -0.25, 0.3])  # fwd traction, fwd braking, back traction, back braking
    out = pid.step(s_des, [0.0] * 4, v, 0.8, v / radius, 0.01)
    np.testing.assert_allclose(slip_ratio(out.omega_cmd_radps * radius, v), s_des, atol=1e-12)


def test_limit_mode_only_ever_reduces_slip_magnitude():
    cfg = SlipPIDConfig(kp=5.0, ki=0.0, mode="limit")
    pid = SlipPID(6, cfg)
    # forward traction: below target -> nothing; above -> slower wheel
    # forward braking (target -0.2): -0.1 -> nothing; -0.4 -> faster wheel
    # backward traction (target -0.2): -0.4 -> less negative wheel speed (positive output)
    s_des = [0.2, 0.2, -0.2, -0.2, -0.2, -0.2]
    s_meas = [0.1, 0.4, -0.1, -0.4, -0.1, -0.4]
    v = [1.0, 1.0, 1.0, 1.0, -1.0, -1.0]
    out = pid.step(s_des, s_meas, v, 1.0, [6.0, 6.0, 6.0, 6.0, -6.0, -6.0], 0.01).pid_out_radps
    assert out[0] == 0.0 and out[1] < 0.0
    assert out[2] == 0.0 and out[3] > 0.0
    assert out[4] == 0.0 and out[5] > 0.0


def test_limit_mode_integrator_drains_when_slip_falls_below_target():
    pid = SlipPID(1, SlipPIDConfig(kp=0.0, ki=10.0, mode="limit", integral_limit_radps=1.0))
    for _ in range(100):
        _step(pid, 0.2, 0.4)  # too much slip for 1 s: integrator pulls the wheel back
    assert pid.integral_radps[0] == pytest.approx(-1.0)
    for _ in range(200):
        out = _step(pid, 0.2, 0.0)  # slip well below target: back to the plain command
    assert pid.integral_radps[0] == 0.0 and out.pid_out_radps[0] == 0.0


def test_rate_limit_bounds_the_output_slew():
    pid = SlipPID(1, SlipPIDConfig(kp=100.0, rate_limit_radps2=20.0, output_limit_radps=5.0))
    outs = [_step(pid, 0.5, 0.0).pid_out_radps[0] for _ in range(40)]
    assert outs[0] == pytest.approx(0.2)  # 20 rad/s^2 x 10 ms
    assert np.all(np.diff(outs) <= 0.2 + 1e-12)
    assert outs[-1] == pytest.approx(5.0)  # reaches the output limit after 0.25 s


def test_new_config_fields_are_validated():
    with pytest.raises(ValueError, match="mode"):
        SlipPIDConfig(mode="bang-bang")
    with pytest.raises(ValueError, match="wheel_radius_m"):
        SlipPIDConfig(wheel_radius_m=0.0)
    with pytest.raises(ValueError, match="rate_limit"):
        SlipPIDConfig(rate_limit_radps2=-1.0)


def test_feedforward_settles_much_faster_than_the_thesis_p_controller():
    """Lagged wheel (40 ms velocity loop) at constant ground speed, target slip 0.3 from a
    zero-slip set-point: with feed-forward the slip is within 0.01 of the target after 0.25 s;
    the thesis P controller (Kp 1) has barely moved."""
    radius, dt, tau, v = 0.165, 0.01, 0.04, 1.0

    def run(cfg, ticks=25):
        omega_ll = v / radius
        omega = omega_ll
        pid = SlipPID(1, cfg)
        for _ in range(ticks):
            s = slip_ratio(omega * radius, v)
            cmd = pid.step([0.3], [s], [v], v, [omega_ll], dt).omega_cmd_radps[0]
            omega += (1.0 - math.exp(-dt / tau)) * (cmd - omega)
        return slip_ratio(omega * radius, v)

    ff = SlipPIDConfig(kp=2.0, ki=10.0, wheel_radius_m=radius, output_limit_radps=10.0)
    assert run(ff) == pytest.approx(0.3, abs=0.01)
    assert run(SlipPIDConfig()) < 0.05
