"""Mission-suite policies (design §12): one interface, hand-worked limits."""

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


class _FirmClassPredictor:
    """Stands in for the online predictor: always a confident class, body speed ``v_mps``."""

    def __init__(self, robot, class_id, v_mps=0.0):
        from terrainml.lookup.table import DesiredSlipTable
        from types import SimpleNamespace
        self.table = DesiredSlipTable.build(robot)
        self.class_names = None
        self.estimator = SimpleNamespace(v_long=np.full(robot.n_wheels, float(v_mps)))
        self._msg = SimpleNamespace(terrain_class=int(class_id), fallback=False, fallback_reason="")

    def step(self, sample):
        return self._msg


def _peak_current_a(robot, ctrl, cid):
    """Motor current (A) per wheel at the class's gross-thrust peak: H/W x W_i x R / k_t."""
    h_w = ctrl.curves.get(cid)[4]
    return h_w * np.asarray(robot.static_wheel_loads_n()) * robot.wheel_radius_m / robot.torque_constant_nm_per_a


def test_served_firm_class_at_a_stall_escalates_to_the_safe_cap(robot):
    """Greenhouse tuning seeds, dry sand into wet mud: the fused class lags a terrain
    change and never goes stale at a stall, so a firm class's cap held the wheels short of the
    soil's peak for up to 48 s. A wheel held at the served cap with the body stalled must get the
    largest traction target of all classes after ``stall_s``, and the class again after ``hold_m``."""
    from terrainml.classes import TERRAIN_CLASSES
    pred = _FirmClassPredictor(robot, 1)          # compacted_dirt, s_T 0.142
    ctrl = bl.terrain_aware(robot, predictor=pred, refine=False)
    firm = pred.table.target(1, "traction")
    largest = max(pred.table.target(c, "traction") for c in range(len(TERRAIN_CLASSES)))
    assert largest > firm + 0.2
    caps = []
    i_peak = float(np.max(_peak_current_a(robot, ctrl, 1)))   # the wheel pulls at the class's peak
    for k in range(100):                          # 1 s: wheel spins at 3 rad/s, body at rest
        ctrl(_sample(robot, k * 0.01, 3.0, 3.0, current=i_peak))
        caps.append(float(ctrl.last_cap[0]))
    assert np.allclose(caps[:40], firm)           # within stall_s (0.5 s) the class is served
    assert np.allclose(caps[-40:], largest)       # then the safe cap
    # the body moves at the command (no stall): the safe cap holds for 2 m, then the class again
    pred.estimator.v_long[:] = 0.5
    t0 = 1.0
    caps = []
    for k in range(600):                          # 6 s at 0.5 m/s = 3 m
        ctrl(_sample(robot, t0 + k * 0.01, 3.0, 0.5 / robot.wheel_radius_m, current=i_peak))
        caps.append(float(ctrl.last_cap[0]))
    travelled_m = 0.5 * 0.01 * np.arange(1, 601)
    assert np.allclose(np.array(caps)[travelled_m < 1.9], largest)
    assert np.allclose(np.array(caps)[travelled_m > 2.1], firm)


def test_served_class_is_kept_at_a_start_that_builds_up(robot):
    """No stall at the cap (the wheel follows its command, the limit does not bind): no escalation."""
    pred = _FirmClassPredictor(robot, 6, v_mps=0.0)   # dry_sand
    ctrl = bl.terrain_aware(robot, predictor=pred, refine=False)
    for k in range(200):
        ctrl(_sample(robot, k * 0.01, 0.0, 0.0))      # standing, zero command: nothing binds
    assert np.allclose(ctrl.last_cap, pred.table.target(6, "traction"))


def test_class_from_before_an_unhealthy_episode_is_not_served_until_reclassified(robot):
    """Greenhouse tuning seed compacted_dirt 5004: the estimator went unhealthy while
    the robot drove onto a tilled-loam patch; the odometer counts no unhealthy tick, so the class
    held from before (compacted dirt, s_T 0.142) came back unaged after it and stalled the wheels
    on the patch (+4.9% energy against no control). The class is served again only once a window
    has been classified after the episode."""
    from types import SimpleNamespace
    from terrainml.classes import TERRAIN_CLASSES
    pred = _FirmClassPredictor(robot, 1)
    ctrl = bl.terrain_aware(robot, predictor=pred, refine=False)
    firm = pred.table.target(1, "traction")
    largest = max(pred.table.target(c, "traction") for c in range(len(TERRAIN_CLASSES)))

    def tick(t, fallback, reason, age_s):
        pred._msg = SimpleNamespace(terrain_class=-1 if fallback else 1, fallback=fallback,
                                    fallback_reason=reason, classification_age_s=age_s)
        ctrl(_sample(robot, t, 0.0, 0.0))
        return float(ctrl.last_cap[0])

    assert tick(0.00, False, "", 0.05) == pytest.approx(firm)
    caps_sick = [tick(0.01 * k, True, "estimator_unhealthy", 0.05 + 0.01 * k) for k in range(1, 51)]
    # healthy again, but the last classification (age 0.55 s and growing) predates the episode
    caps_old = [tick(0.5 + 0.01 * k, False, "", 0.55 + 0.01 * k) for k in range(1, 101)]
    cap_new = tick(1.51, False, "", 0.005)       # a window classified 5 ms ago: after the episode
    assert np.allclose(caps_sick, largest)
    assert np.allclose(caps_old, largest)
    assert cap_new == pytest.approx(firm)
    # without the rule the old class comes straight back (what the tuning seed did)
    ctrl = bl.terrain_aware(robot, predictor=pred, refine=False, escalation={"relearn": False})
    tick(0.0, True, "estimator_unhealthy", 0.05)
    assert tick(0.01, False, "", 0.06) == pytest.approx(firm)


def test_served_cap_that_loses_speed_escalates_before_the_stall(robot):
    """Greenhouse tuning seeds: a firm class's cap on softer ground holds the wheels
    below the slip the soil needs to keep the speed, and the body slows under a steady command.
    A wheel held at its cap while the body loses speed faster than ``lag_decel_mps2`` behind its
    command escalates to the safe cap after ``lag_s``, while the body still moves, instead of
    waiting for the stall (below 0.1 m/s for 0.5 s)."""
    from terrainml.classes import TERRAIN_CLASSES

    def run(**escalation):
        pred = _FirmClassPredictor(robot, 1, v_mps=0.45)   # compacted_dirt, s_T 0.142
        ctrl = bl.terrain_aware(robot, predictor=pred, refine=False, escalation=escalation)
        largest = max(pred.table.target(c, "traction") for c in range(len(TERRAIN_CLASSES)))
        cmd = 0.5 / robot.wheel_radius_m                     # 0.5 m/s asked throughout
        i_peak = float(np.max(_peak_current_a(robot, ctrl, 1)))
        for k in range(60):                                  # 0.6 s, the body slows at 0.6 m/s^2
            v = 0.45 - 0.006 * k
            pred.estimator.v_long[:] = v
            ctrl(_sample(robot, k * 0.01, cmd, cmd, current=i_peak))
            if abs(float(ctrl.last_cap[0]) - largest) < 1e-12:
                return v
        return None

    v_at = run()
    assert v_at is not None and v_at > 0.15    # escalated while the body still moved (stall: < 0.1)
    assert run(lag_decel_mps2=None) is None    # the stall rule alone has not fired yet
    assert run(lag_decel_mps2=1.0) is None     # slowing below the threshold: no escalation


def test_served_cap_on_weak_thrust_contradicts_the_class(robot):
    """Greenhouse tuning seed compacted_dirt 5004: on its own ground a wheel reaches the
    class's traction-peak slip only near the class's peak thrust. Held at compacted dirt's cap on
    a tilled-loam patch it pulled about a third of that, and the cap held the robot back at low
    demand. A wheel held at its cap for 0.1 s on less than ``thrust_gate`` (0.5) of the class's
    gross-thrust peak escalates to the safe cap; at the peak thrust it keeps the class."""
    from terrainml.classes import TERRAIN_CLASSES

    def run(share, **escalation):
        pred = _FirmClassPredictor(robot, 1, v_mps=0.4)       # compacted_dirt, s_T 0.142
        ctrl = bl.terrain_aware(robot, predictor=pred, refine=False, escalation=escalation)
        largest = max(pred.table.target(c, "traction") for c in range(len(TERRAIN_CLASSES)))
        i = share * _peak_current_a(robot, ctrl, 1)          # (N,) A
        cmd = 0.5 / robot.wheel_radius_m                      # slip 0.2 > 0.142: the cap binds
        first, hit = None, None
        for k in range(50):                                   # 0.5 s at a steady 0.4 m/s
            s = _sample(robot, k * 0.01, cmd, cmd)
            s.update({f"wheel{j}_current_a": float(i[j - 1]) for j in range(1, robot.n_wheels + 1)})
            ctrl(s)
            if first is None and ctrl.limiting.any():
                first = k
            if hit is None and abs(float(ctrl.last_cap[0]) - largest) < 1e-12:
                hit = k
        return first, hit

    first, hit = run(0.3)                 # a third of the class's peak thrust: the class is wrong
    assert first is not None and hit is not None and 9 <= hit - first <= 12    # 0.1 s at the cap
    assert run(1.0)[1] is None            # at the class's peak thrust: the class is kept
    assert run(0.6)[1] is None            # above the gate: kept
    assert run(0.3, thrust_gate=None)[1] is None   # without the gate the cap holds (the old way)


def test_weak_thrust_gate_needs_a_measured_current(robot):
    """A robot that logs no motor current (NaN) gives no thrust: the gate cannot contradict the
    class, so the class is kept (the other escalations still apply)."""
    pred = _FirmClassPredictor(robot, 1, v_mps=0.4)
    ctrl = bl.terrain_aware(robot, predictor=pred, refine=False)
    cmd = 0.5 / robot.wheel_radius_m
    for k in range(50):
        ctrl(_sample(robot, k * 0.01, cmd, cmd, current=float("nan")))
    assert ctrl.limiting.any()                                   # held at the cap throughout
    assert np.allclose(ctrl.last_cap, pred.table.target(1, "traction"))


def test_unknown_ground_turns_on_refinement_of_the_safe_cap(robot):
    """On ``unknown_terrain`` the safe cap is served refined, read against the nominal
    curve of the class whose traction peak is the cap (the largest of the classes); any other
    fallback serves it unrefined (no class, no curve)."""
    from types import SimpleNamespace
    from terrainml.classes import TERRAIN_CLASSES
    pred = _FirmClassPredictor(robot, 1)
    ctrl = bl.terrain_aware(robot, predictor=pred, refine=True)
    targets = {c: pred.table.target(c, "traction") for c in range(len(TERRAIN_CLASSES))}
    cap_class = max(targets, key=targets.get)
    for reason, want in (("unknown_terrain", cap_class), ("uncertain_classification", None),
                         ("stale_classification", None)):
        pred._msg = SimpleNamespace(terrain_class=-1, fallback=True, fallback_reason=reason,
                                    classification_age_s=0.1)
        ctrl(_sample(robot, 0.0, 0.0, 0.0))
        s_t, _, cid = ctrl.targets(ctrl, _sample(robot, 0.01, 0.0, 0.0))
        assert cid == want and np.allclose(s_t, targets[cap_class])
        assert np.allclose(ctrl.last_cap, targets[cap_class])  # nothing learnt yet: the cap itself
    assert np.isfinite(ctrl.curves.get(cap_class)[2]).any()    # a nominal curve to refine against
    off = bl.ServedTargets(refine_unknown=False)
    pred._msg = SimpleNamespace(terrain_class=-1, fallback=True, fallback_reason="unknown_terrain",
                                classification_age_s=0.1)
    assert off(ctrl, _sample(robot, 0.02, 0.0, 0.0))[2] is None


def test_refine_unknown_only_refines_the_safe_cap_on_unknown_ground(robot):
    """``terrain_aware(refine="unknown")`` (the ``terrain-aware-refine-unknown`` policy): a served
    class is capped at its table target with no curve to refine against; on ``unknown_terrain``
    the safe cap gets the cap class's curve, as with ``refine=True``."""
    from types import SimpleNamespace
    pred = _FirmClassPredictor(robot, 1)
    ctrl = bl.terrain_aware(robot, predictor=pred, refine="unknown")
    assert ctrl.refiner is not None
    ctrl(_sample(robot, 0.0, 0.0, 0.0))
    s_t, _, cid = ctrl.targets(ctrl, _sample(robot, 0.01, 0.0, 0.0))
    assert cid is None and np.allclose(s_t, pred.table.target(1, "traction"))
    full = bl.terrain_aware(robot, predictor=_FirmClassPredictor(robot, 1), refine=True)
    full(_sample(robot, 0.0, 0.0, 0.0))
    assert full.targets(full, _sample(robot, 0.01, 0.0, 0.0))[2] == 1
    pred._msg = SimpleNamespace(terrain_class=-1, fallback=True, fallback_reason="unknown_terrain",
                                classification_age_s=0.1)
    ctrl(_sample(robot, 0.02, 0.0, 0.0))
    assert ctrl.targets(ctrl, _sample(robot, 0.03, 0.0, 0.0))[2] is not None
    with pytest.raises(ValueError, match="refine must be"):
        bl.terrain_aware(robot, predictor=pred, refine="sometimes")
