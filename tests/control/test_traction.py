"""SlipController: measured samples -> per-wheel corrections (design §12), without the simulator."""

from __future__ import annotations

import numpy as np
import pytest

from terrainml.control.traction import ControlSettings, FixedTargetTable, SlipController, tuned_config
from terrainml.estimation.slip import slip_ratio
from terrainml.testing import kinematic_run, trapezoid_speed
from terrainml.robot import load_robot

CRUISE_MPS = 0.8


@pytest.fixture(scope="module")
def robot():
    return load_robot()


def _drive(robot, ctrl, true_slip: float, duration_s: float = 8.0):
    """Feed a kinematic run (constant true slip at cruise); the low-level set-point is the
    wheel's actual speed (the wheel follows its velocity loop, the body lags by the slip)."""
    table = kinematic_run(robot, duration_s=duration_s, seed=3, slip=true_slip,
                          vx=lambda t: trapezoid_speed(t, CRUISE_MPS, 1.0, 1.0, duration_s + 10))
    cols = [c for c in table.columns if not c.startswith("gt_")]
    n = robot.n_wheels
    outs = []
    for rec in table[cols].to_dict("records"):
        vx = trapezoid_speed(np.array(rec["t_s"]), CRUISE_MPS, 1.0, 1.0, duration_s + 10)
        for i in range(1, n + 1):  # straight line: every wheel's set-point is vx / (1 - s) / R
            rec[f"wheel{i}_cmd_omega_radps"] = float(vx) / (1.0 - true_slip) / robot.wheel_radius_m
        out = ctrl(rec)
        outs.append(np.zeros(n) if out is None else np.asarray(out))
    return table, np.array(outs)


def test_none_policy_never_corrects(robot):
    ctrl = SlipController(robot, "none")
    assert ctrl({"t_s": 0.0}) is None


def test_fixed_limiter_pulls_an_overslipping_wheel_to_the_target(robot):
    """True slip 0.3 at cruise against the fixed 0.1 target (the wheels of a kinematic run do
    not respond to the command, so the PI trim is off): the limiter's feed-forward makes the
    commanded wheel speed the one of slip 0.1 at the true wheel speed over ground."""
    ctrl = SlipController(robot, "fixed", ControlSettings(pid=tuned_config(robot, kp=0.0, ki=0.0)))
    _, outs = _drive(robot, ctrl, true_slip=0.3)
    omega_cmd = CRUISE_MPS / 0.7 / robot.wheel_radius_m + outs[-100:].mean(axis=0)
    s_cmd = slip_ratio(omega_cmd * robot.wheel_radius_m, CRUISE_MPS)
    np.testing.assert_allclose(s_cmd, 0.1, atol=0.02)
    assert np.all(outs <= 0.0)  # a limiter never spins a wheel faster than commanded


def test_terrain_aware_oracle_leaves_cruise_slip_below_the_target_alone(robot):
    """wet_mud steady target 0.42; a wheel cruising at 0.3 true slip needs no correction."""
    ctrl = SlipController(robot, "terrain-aware", true_class=7)
    assert ctrl.classifier == "oracle"
    _, outs = _drive(robot, ctrl, true_slip=0.3)
    assert np.abs(outs[-300:]).max() == 0.0


def test_fixed_table_signs():
    t = FixedTargetTable()
    assert (t.target(5, "traction"), t.target(5, "steady"), t.target(5, "braking"),
            t.target(5, "idle")) == (0.1, 0.1, -0.1, 0.0)


def test_feedforward_without_setpoints_is_a_clear_error(robot):
    ctrl = SlipController(robot, "fixed", ControlSettings(pid=tuned_config(robot)))
    table = kinematic_run(robot, duration_s=1.0, seed=1)
    rec = table[[c for c in table.columns if not c.startswith("gt_")]].iloc[0].to_dict()
    with pytest.raises(ValueError, match="wheel1_cmd_omega_radps"):
        ctrl(rec)


def test_bad_policy_rejected(robot):
    with pytest.raises(ValueError, match="policy"):
        SlipController(robot, "aggressive")


def test_default_law_is_the_slip_limiter_and_a_pid_config_selects_the_pid(robot):
    """The limiter is the default; the thesis PID stays reachable explicitly."""
    assert SlipController(robot, "fixed").law == "limiter"
    assert SlipController(robot, "fixed").pid is None
    assert SlipController(robot, "fixed", ControlSettings(pid=tuned_config(robot))).law == "pid"
    assert SlipController(robot, "fixed", ControlSettings(law="pid")).config == tuned_config(robot)
    with pytest.raises(ValueError, match="law"):
        SlipController(robot, "fixed", ControlSettings(law="bang-bang"))


def _stalled_sample(robot, t_s: float, omega_radps: float) -> dict:
    """The robot at rest (no camera motion, no acceleration) with every wheel spinning."""
    n = robot.n_wheels
    s = {"t_s": t_s, "imu_ax_mps2": 0.0, "imu_ay_mps2": 0.0, "imu_az_mps2": 9.81,
         "imu_yaw_rate_radps": 0.0, "cam_vx_mps": 0.0, "cam_vy_mps": 0.0,
         "cam_yaw_rate_radps": 0.0, "cam_yaw_rad": 0.0, "cam_confidence": 3.0}
    for i in range(1, n + 1):
        s.update({f"wheel{i}_omega_radps": omega_radps, f"wheel{i}_steer_rad": 0.0,
                  f"wheel{i}_current_a": 5.0, f"wheel{i}_cmd_omega_radps": omega_radps})
    return s


def test_limiter_law_holds_a_wheel_spinning_at_a_stall_where_the_pid_lets_go(robot):
    """Wheels commanded and spinning at 3 rad/s (0.5 m/s surface) while the body stays at rest
    (slip 1 against the wet-mud cap 0.52): the PID's enable rule (body >= 0.05 m/s) keeps it off;
    the limiter pulls every wheel down, and keeps holding for as long as the stall lasts."""
    outs = {}
    for law in ("limiter", "pid"):
        ctrl = SlipController(robot, "terrain-aware", ControlSettings(law=law), true_class=7)
        outs[law] = np.array([ctrl(_stalled_sample(robot, 0.01 * k, 3.0)) for k in range(300)])
    assert np.all(outs["pid"] == 0.0)
    assert np.all(outs["limiter"][-100:] < -2.0)         # most of the 3 rad/s taken back
    assert np.all(outs["limiter"] <= 0.0)                # a limiter never spins a wheel up
