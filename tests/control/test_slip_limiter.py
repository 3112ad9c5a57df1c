"""Slip limiter (design §12): hand-worked cases and a towed-load start in the simulator."""

from __future__ import annotations

import math

import numpy as np
import pytest

from terrainml.control.slip_limiter import SlipLimiter, SlipLimiterConfig, regularised_slip

R = 0.165
DT = 0.01


def _lim(**kw) -> SlipLimiter:
    return SlipLimiter(1, SlipLimiterConfig(wheel_radius_m=R, **kw))


def test_regularised_slip_is_finite_at_rest():
    # (u - v) / max(|u|, |v|, floor): at rest 0; creeping 0.05 m/s at a stall 0.05 / 0.1 = 0.5
    np.testing.assert_allclose(regularised_slip([0.0, 0.05, 1.0, 0.8], [0.0, 0.0, 0.8, 1.0], 0.1),
                               [0.0, 0.5, 0.2, -0.2])


def test_keeps_acting_at_a_stall_and_never_releases():
    """Body at 0, wheel commanded at 3 rad/s (0.495 m/s), cap 0.4. The shear slip builds while
    the wheel turns; once it passes the target the ceiling is u_hold + kp e = 0 + 0.5 e <= 0, so
    the command is pulled towards 0 (not released: the offset stays at the command's size)."""
    lim = _lim(ki=0.0)
    omega = 3.0
    outs = []
    for _ in range(300):                      # the wheel follows its command exactly
        out = lim.step([omega], [3.0], [0.0], [0.4], DT)
        omega = float(out.omega_out_radps[0])
        outs.append(omega)
    assert lim.slip_shear[0] > 0.4 - 1e-9        # the soil's shear slip reached the target
    assert outs[-1] * R < 0.01                   # held, not spinning (released would be 0.495)
    assert bool(out.limiting[0])


def test_creeps_up_to_the_target_from_rest():
    """From rest at a stall the ceiling is max(kp (s_T - s), creep): 0.5 * 0.4 = 0.2 m/s at first,
    so the wheel turns and builds shear displacement (it does not sit at 0)."""
    lim = _lim(ki=0.0, clamp_rate_mps2=1e6)
    out = lim.step([0.0], [3.0], [0.0], [0.4], DT)
    assert out.omega_out_radps[0] * R == pytest.approx(0.5 * 0.4, abs=1e-9)


def test_cruise_below_the_cap_is_untouched():
    lim = _lim()
    v = 0.8
    omega_cmd = v / (1 - 0.2) / R            # the soil's cruise slip 0.2, cap 0.4
    for _ in range(500):
        out = lim.step([omega_cmd], [omega_cmd], [v], [0.4], DT)
    assert out.offset_radps[0] == 0.0
    assert lim.slip_shear[0] == pytest.approx(0.2, abs=1e-6)


def test_release_is_smooth_at_the_release_rate():
    """A clamped wheel whose cap is lifted: the offset returns at <= release_rate (1 m/s^2 of
    surface speed, i.e. 0.01 m/s per tick), never in one step."""
    lim = _lim(ki=0.0)
    for _ in range(200):                      # stall, wheel held: ceiling kp s_T = 0.2 m/s
        lim.step([0.0], [3.0], [0.0], [0.4], DT)
    off0 = lim.offset_mps[0]
    assert off0 == pytest.approx(0.5 * 0.4 - 3.0 * R)
    steps = []
    for _ in range(20):                       # cap lifted: slip target far above the slip
        prev = lim.offset_mps[0]
        lim.step([3.0], [3.0], [0.8], [0.95], DT)
        steps.append(lim.offset_mps[0] - prev)
    assert max(steps) <= 1.0 * DT + 1e-12
    assert lim.offset_mps[0] == pytest.approx(off0 + 20 * 0.01)


def test_anti_windup_integral_only_while_binding_and_clamped():
    lim = _lim(ki=50.0, integral_limit_mps=0.3)
    for _ in range(300):                       # binding and over target: winds down to the clamp
        lim.step([3.0], [3.0], [0.0], [0.4], DT)
    assert lim.integral_mps[0] == pytest.approx(-0.3)
    for _ in range(300):                       # below target, not binding: drains to 0
        lim.step([0.8 / R], [0.8 / R], [0.8], [0.4], DT)
    assert lim.integral_mps[0] == 0.0


def test_braking_floor_keeps_the_wheel_turning():
    """Forward braking at 1 m/s with the command at 0.2 m/s and s_B = -0.2: floor u >= v - max(0.2
    v, creep) = 0.8 m/s; the offset is positive (the limiter lifts a locking wheel)."""
    lim = _lim(clamp_rate_mps2=1e6)
    out = lim.step([0.2 / R], [0.2 / R], [1.0], [-0.2], DT)
    assert out.omega_out_radps[0] * R == pytest.approx(0.8)


def test_bad_input_passes_the_command_through():
    lim = SlipLimiter(2, SlipLimiterConfig(wheel_radius_m=R))
    out = lim.step([math.nan, 1.0], [2.0, 0.0], [0.0, 0.0], [0.4, 0.4], DT)
    np.testing.assert_array_equal(out.omega_out_radps, [2.0, 0.0])
    assert np.all(np.isfinite(out.offset_radps))


def test_config_checked():
    with pytest.raises(ValueError, match="creep_mps"):
        SlipLimiterConfig(wheel_radius_m=R, creep_mps=0.0)


# ------------------------------------------------------------------ simulator: towed-load start
def _towed_start(policy: str, load_w: float = 0.10, duration_s: float = 30.0):
    from terrainml.control import baselines as bl
    from terrainml.experiments.closed_loop import closed_loop_hook
    from towed_sand import towed_sand_start
    from terrainml.sim import physics as ph

    sim, rb, cid, peak = towed_sand_start(5000, duration_s, load_w)
    ctrl = None if policy == "none" else bl.oracle_cap(rb, lambda: peak, lambda t: cid)
    res = sim.run(controller=None if ctrl is None else closed_loop_hook(sim, ctrl))
    x = res.log[:, ph.L_X]
    finite = np.isfinite(res.log).all(axis=1)
    # the distance before any non-finite row (the uncontrolled run digs in without bound, see
    # the slip limiter's report in docs/control.md)
    upto = np.argmin(finite) if not finite.all() else len(x)
    return float(np.max(x[:upto])), res, upto


@pytest.mark.acceptance
def test_towed_start_on_dry_sand_travels_far_more_than_no_control():
    """Dry sand, a cart of 0.10 W rolling resistance, a 0.8 m/s step command for 30 s.

    No control spins the wheels (slip ~1) and digs in; the limiter at the true peak holds the
    shear slip at the peak and keeps the robot moving."""
    x_none, _, _ = _towed_start("none")
    x_cap, res, upto = _towed_start("oracle-cap")
    assert upto == len(res.log)                        # the controlled run stays finite
    assert x_cap > 2.0 and x_cap > 3.0 * x_none
    assert float(np.nanmax(res.wblock("sinkage"))) < 0.1   # no dig-in


def test_build_up_gain_lifts_the_ceiling_below_target_only():
    """kp_build 6 m/s per unit slip, kp 2: from rest at a stall (s = 0, cap 0.4) the ceiling is
    0 + 6 * 0.4 = 2.4 m/s, above the 0.495 m/s command, so nothing is limited (the drive keeps its
    full speed error and torque); above target (s = 0.5) the ceiling is 0 + 2 * (0.4 - 0.5) < 0,
    clipped at 0: the wheel is pulled to rest as before."""
    lim = _lim(ki=0.0, kp_mps=2.0, kp_build_mps=6.0, clamp_rate_mps2=1e6)
    out = lim.step([0.0], [3.0], [0.0], [0.4], DT)
    assert out.offset_radps[0] == 0.0 and not bool(out.limiting[0])
    lim.slip_shear[:] = 0.5
    out = lim.step([0.0], [3.0], [0.0], [0.4], DT)     # u = v = 0: the shear slip holds
    assert bool(out.limiting[0]) and out.omega_out_radps[0] == pytest.approx(0.0, abs=1e-12)


def test_build_up_gain_partial_ceiling_hand_worked():
    """Body at 0.3 m/s, shear slip 0.3, cap 0.4, kp_build 1.0: u_hold = 0.3 / 0.6 = 0.5 m/s,
    ceiling 0.5 + 1.0 * 0.1 = 0.6 m/s (the shear slip is set directly; the wheel is measured at
    0.5 m/s, so one tick moves it by a(0.4 - 0.3) with a = 1 - exp(-0.5 * 0.01 / 0.14))."""
    lim = _lim(ki=0.0, kp_build_mps=1.0, clamp_rate_mps2=1e6)
    lim.slip_shear[:] = 0.3
    out = lim.step([0.5 / R], [1.0 / R], [0.3], [0.4], DT)
    s1 = 0.3 + (-math.expm1(-0.5 * DT / 0.14)) * (0.4 - 0.3)
    assert lim.slip_shear[0] == pytest.approx(s1)
    assert out.omega_out_radps[0] * R == pytest.approx(0.5 + 1.0 * (0.4 - s1))


def test_build_up_gain_checked():
    with pytest.raises(ValueError, match="kp_build_mps"):
        SlipLimiterConfig(wheel_radius_m=R, kp_build_mps=0.0)
    assert SlipLimiterConfig(wheel_radius_m=R).kp_build_mps is None


def test_shear_slip_follows_the_motion_at_a_zero_command():
    """A stop: command 0, wheel at rest, body still rolling at 0.1 m/s. The shear slip obeys (1)
    exactly: s(t) = s0 + (-1 - s0)(1 - exp(-v t / L)) with s_inst = (0 - v) / v = -1."""
    cfg = SlipLimiterConfig(wheel_radius_m=0.165, contact_length_m=0.14)
    lim = SlipLimiter(1, cfg)
    lim.slip_shear[:] = 0.4                      # at the cap when the stop begins
    for _ in range(10):                          # 0.1 s
        lim.step([0.0], [0.0], [0.1], [0.4], dt_s=0.01)
    want = 0.4 + (-1.0 - 0.4) * (1.0 - math.exp(-0.1 * 0.1 / 0.14))
    assert lim.slip_shear[0] == pytest.approx(want, rel=1e-9)


def test_a_reversal_flips_the_shear_slip_into_the_new_direction():
    """0.4 of traction slip driving forward is -0.4 in the frame of a backward command."""
    lim = SlipLimiter(1, SlipLimiterConfig(wheel_radius_m=0.165))
    lim.slip_shear[:] = 0.4
    out = lim.step([0.0], [-1.0], [0.0], [0.4], dt_s=0.01)  # everything at rest: (1) holds
    assert lim.slip_shear[0] == pytest.approx(-0.4)
    assert out.slip_shear[0] == pytest.approx(0.4)             # signed like the wheel: unchanged


def test_rest_relaxation_decays_the_shear_slip_at_rest_only():
    """Wheel and body at rest: s decays as exp(-t / rest_relax_s); without it (None) s holds."""
    hold = SlipLimiter(1, SlipLimiterConfig(wheel_radius_m=0.165))
    relax = SlipLimiter(1, SlipLimiterConfig(wheel_radius_m=0.165, rest_relax_s=0.5))
    for lim in (hold, relax):
        lim.slip_shear[:] = 0.3
        for _ in range(50):                                    # 0.5 s, a command of 1 rad/s
            lim.step([0.0], [1.0], [0.0], [0.15], dt_s=0.01)
    assert hold.slip_shear[0] == pytest.approx(0.3)
    assert relax.slip_shear[0] == pytest.approx(0.3 * math.exp(-1.0), rel=1e-9)
    with pytest.raises(ValueError):
        SlipLimiterConfig(wheel_radius_m=0.165, rest_relax_s=0.0)
