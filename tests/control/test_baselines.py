"""Mission-suite policies (design §12, issue 20): one interface, hand-worked limits."""

from __future__ import annotations

import numpy as np
import pytest

from terrainml.control import baselines as bl
from terrainml.robot import load_robot


@pytest.fixture(scope="module")
def robot():
    return load_robot()


def _sample(robot, t, omega, cmd, current=0.0):
    # a stalled body: IMU at rest, the tracking camera sees no motion (confidence high)
    s = {"t_s": t, "imu_ax_mps2": 0.0, "imu_ay_mps2": 0.0, "imu_az_mps2": 9.81,
         "imu_yaw_rate_radps": 0.0, "cam_vx_mps": 0.0, "cam_vy_mps": 0.0,
         "cam_yaw_rate_radps": 0.0, "cam_yaw_rad": 0.0, "cam_confidence": 3.0}
    for i in range(1, robot.n_wheels + 1):
        s[f"wheel{i}_omega_radps"] = omega
        s[f"wheel{i}_cmd_omega_radps"] = cmd
        s[f"wheel{i}_current_a"] = current
    return s


def test_no_control_is_no_hook(robot):
    assert bl.no_control(robot) is None


def test_current_limit_is_mu_h_w_r_over_kt(robot):
    """Limit per wheel = (gross-thrust peak / W) * W_i * R / k_t, from the class's nominal curve."""
    from terrainml.lookup import terramechanics as tm
    ctrl = bl.CurrentLimitController(robot, lambda t: 6)
    w = np.mean(robot.static_wheel_loads_n())
    s = np.linspace(0, 0.99, 991)
    mu_h = tm.gross_thrust_n(tm.nominal_params(6), w, s, robot).max() / w
    np.testing.assert_allclose(ctrl.limit_a(6), mu_h * np.asarray(robot.static_wheel_loads_n())
                               * robot.wheel_radius_m / robot.torque_constant_nm_per_a)


def test_current_limit_lowers_the_command_only_above_the_limit(robot):
    ctrl = bl.CurrentLimitController(robot, lambda t: 6, gain=10.0)
    lim = ctrl.limit_a(6)[0]
    out = ctrl(_sample(robot, 0.0, 3.0, 3.0, current=lim - 1.0))
    np.testing.assert_array_equal(out, 0.0)
    out = ctrl(_sample(robot, 0.01, 3.0, 3.0, current=lim + 2.0))
    np.testing.assert_allclose(out, -10.0 * 2.0 * 0.01)          # gain * excess * dt


def test_accel_limit_slews_the_command_at_k_mu_g(robot):
    ctrl = bl.AccelLimitController(robot, lambda t: 6, k=0.8)
    mu = ctrl.curves.get(6)[3]
    ctrl(_sample(robot, 0.0, 0.0, 0.0))
    out = ctrl(_sample(robot, 0.01, 0.0, 5.0))                    # a step to 5 rad/s
    np.testing.assert_allclose(out + 5.0, 0.8 * mu * 9.81 / robot.wheel_radius_m * 0.01)


def test_limiter_policies_share_the_interface(robot):
    """fixed / oracle / oracle-cap: a stalled wheel spinning at 3 rad/s is pulled down, not released."""
    ctrls = [bl.fixed_cap(robot), bl.oracle(robot, lambda t: 6),
             bl.oracle_cap(robot, lambda: [0.4] * robot.n_wheels, lambda t: 6)]
    for ctrl in ctrls:
        for k in range(50):
            out = ctrl(_sample(robot, k * 0.01, 3.0, 3.0))
        assert out.shape == (robot.n_wheels,)
        assert np.all(out < -1.0) and ctrl.n_ticks == 50


def test_missing_setpoints_are_a_clear_error(robot):
    with pytest.raises(ValueError, match="wheel1_cmd_omega_radps"):
        bl.fixed_cap(robot)({"t_s": 0.0, "wheel1_omega_radps": 0.0})


def test_mission_limiter_config_is_the_tuned_build_up():
    """The mission policies' limiter: kp 2.0, build-up gain 6.0 (docs/control_missions.md);
    from rest at a stall the ceiling 6.0 * s_T lies above a 0.5 m/s command for any s_T >= 0.1."""
    from terrainml.control.baselines import mission_limiter_config
    from terrainml.robot import load_robot

    rb = load_robot(None)
    cfg = mission_limiter_config(rb, ki=0.5)
    assert (cfg.kp_mps, cfg.kp_build_mps, cfg.ki) == (2.0, 6.0, 0.5)
    assert cfg.wheel_radius_m == rb.wheel_radius_m
    assert cfg.kp_build_mps * 0.1 > 0.5
