"""Mission physics: grade, dig-in sinkage, starts from rest, battery energy.

Each test compares the simulator with a hand-worked value from the terramechanics functions and
the robot spec, never with the simulator's own output.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from terrainml.lookup import terramechanics as tm
from terrainml.robot import load_robot
from terrainml.sim import Simulator
from terrainml.sim import physics as ph
from terrainml.sim.mission_physics import TowedLoad, dig_params
from terrainml.sim.scenarios import straight
from terrainml.sim.terrain import TerrainLayout

ROBOT = load_robot()
W_WHEEL = ROBOT.weight_n / 3.0


def _graded(terrain: str, slope_rad: float, speed: float = 0.6, duration: float = 8.0):
    sc = straight(terrain, speed_mps=speed, duration_s=duration, brake=False)
    sc.layout = TerrainLayout.uniform(terrain).with_grade(slope_x_rad=slope_rad)
    return Simulator(sc, seed=1, params=[tm.nominal_params(terrain)])


@pytest.mark.parametrize("margin_deg, climbs", [(+4.0, False), (-8.0, True)])
def test_grade_steeper_than_traction_peak_cannot_be_climbed(margin_deg, climbs):
    # hand: steady climb needs mu_net >= tan(theta); short grass peaks at mu_net 0.49 (26 deg)
    mu_peak = float(np.max(tm.net_traction_coefficient(tm.nominal_params("short_grass"), W_WHEEL,
                                                        np.linspace(0, 1, 1001))))
    theta = math.atan(mu_peak) + math.radians(margin_deg)
    res = _graded("short_grass", theta).run()
    x_end = res.log[-1, ph.L_X]
    assert np.all(np.isfinite(res.log))
    assert res.body_col("pitch")[-1] == pytest.approx(theta, abs=1e-3)
    if climbs:
        assert x_end > 2.5                                   # about 0.6 m/s for 7 s
    else:
        assert x_end < 0.5                                   # no progress up the grade


def test_gravity_at_standstill_and_pitch_load_transfer():
    # no command: on a 10 deg grade the body is held by the wheels' shear (j holds), and the
    # rear wheel carries more: sum N = m g cos(theta), front-rear difference = 2 m g sin(theta) h / L
    theta = math.radians(10.0)
    sim = _graded("compacted_dirt", theta, speed=0.0, duration=3.0)
    res = sim.run()
    load = res.wblock("load")[-1]
    assert load.sum() == pytest.approx(ROBOT.weight_n * math.cos(theta), rel=0.02)
    wb = ROBOT.wheels[1].x_m - ROBOT.wheels[0].x_m
    shift = 2.0 * ROBOT.mass_kg * 9.81 * math.sin(theta) * ROBOT.com_height_m / wb
    assert load[0] - load[1] == pytest.approx(shift, rel=0.1)       # wheel1 is the rear wheel
    assert abs(res.log[-1, ph.L_X]) < 0.05                          # held (creep below 5 cm)


def test_stall_digs_in_and_travel_recovers():
    # a tool draft above the traction peak stalls the robot on tilled loam; the spinning wheels dig
    # in at about kappa z0 |omega R| / relax (DigParams); releasing the draft, the robot drives on
    # and the dug depth relaxes with travel
    p = tm.nominal_params("tilled_loam")
    sc = straight("tilled_loam", speed_mps=0.5, duration_s=12.0, brake=False, start_s=0.0)
    sim = Simulator(sc, seed=1, params=[p], tool_draft_n=1.5 * ROBOT.weight_n)
    z_hist = []
    while sim.t_s < 3.0:
        sim.step()
        z_hist.append(sim.wheel[ph.W_DIG].copy())
    z_stall = np.array(z_hist)
    assert np.all(np.diff(z_stall, axis=0) >= -1e-12)               # grows progressively
    d = dig_params("tilled_loam")
    z0 = float(tm.static_sinkage_m(p, W_WHEEL))
    rate_hand = d.kappa * z0 * 0.5 / d.relax_m                      # s' -> 1 at a stall, omega R 0.5
    rate = (z_stall[299] - z_stall[199]).mean() / 1.0
    assert rate == pytest.approx(rate_hand, rel=0.35)
    assert abs(sim.body[ph.B_U]) < 0.05
    z_max = sim.wheel[ph.W_DIG].max()
    sim.set_tool_draft_n(0.0)
    x0 = sim.body[ph.B_X]
    while not sim.done:
        sim.step()
    res = sim.result()
    assert sim.body[ph.B_X] - x0 > 1.5                              # drove on
    assert sim.wheel[ph.W_DIG].max() < 0.3 * z_max                  # the dug depth relaxed
    assert res.wblock("sinkage").max() >= z_max


def test_start_from_rest_on_sand_is_physical():
    sc = straight("dry_sand", speed_mps=1.0, duration_s=6.0, brake=False, start_s=0.0)
    sc.command = lambda t, x=0.0, y=0.0, yaw=0.0: (1.0 if t >= 0.2 else 0.0, 0.0, 0.0)  # step start
    res = Simulator(sc, seed=1, params=[tm.nominal_params("dry_sand")]).run()
    lg = res.log
    assert np.all(np.isfinite(lg))
    thrust = res.wblock("thrust")
    sj = res.wblock("slip_j")
    t = res.t_s
    before = t < 0.2
    assert np.all(np.abs(thrust[before]) < 1e-6)                    # no command, no thrust
    # thrust grows from zero with the shear displacement: none while the free slip s_f is taken
    # up (design §6.2, D9), then rising with j
    s_f = tm.nominal_params("dry_sand").free_slip
    free = np.abs(sj) < 0.99 * s_f
    assert np.all(np.abs(thrust[free]) < 1e-6)
    k = int(np.argmax(thrust.min(axis=1) > 0))
    assert k > 0 and np.all(thrust[k] < thrust[k + 3])
    assert np.all(np.abs(sj) <= 1.0)                                # slip transient bounded
    assert lg[-1, ph.L_VX] > 0.5                                    # body accelerated
    assert np.max(np.abs(lg[:, ph.L_AX])) < 10.0                    # no blow-up
    # steady state: the shear-displacement slip equals the calibrated root
    assert sj[t > 4.0].mean() == pytest.approx(tm.steady_slip(tm.nominal_params("dry_sand"), W_WHEEL),
                                               abs=0.02)


def test_battery_energy_is_mechanical_plus_copper_and_driver_losses():
    # motoring uphill all the way (no regeneration): E_batt = integral of (tau w + (tau/k_t)^2 R) / eta
    theta = math.radians(5.0)
    sim = _graded("pavement", theta, speed=0.8, duration=6.0)
    res = sim.run()
    m = ROBOT.motor_or_default
    tau = res.wblock("tau")[1:]
    om = res.wblock("omega")[1:]
    p_e = tau * om + (tau / ROBOT.torque_constant_nm_per_a) ** 2 * m.phase_resistance_ohm
    # each driver draws P_e / eta_drv, or returns eta_regen P_e (only while the robot settles)
    p_bus = np.where(p_e > 0, p_e / m.driver_efficiency, p_e * m.regen_efficiency).sum(axis=1)
    dt = np.diff(res.t_s)
    assert np.sum(np.minimum(p_bus, 0) * dt) > -1e-3 * np.sum(p_bus * dt)
    e_hand = float(np.sum(p_bus * dt))
    assert res.battery_energy_j == pytest.approx(e_hand, rel=0.01)
    assert res.battery_energy_noregen_j == pytest.approx(res.battery_energy_j, rel=1e-3)
    e_mech = float(np.sum((tau * om).sum(axis=1) * dt))
    assert res.energy_j == pytest.approx(e_mech, rel=0.01)
    assert res.battery_energy_j > res.energy_j


def test_towed_cart_adds_inertia_and_grade_load():
    # hand: pulling a cart of mass M with C_rr c on level pavement at constant speed, the hitch
    # force is c (1 - tongue) M g; the tongue load adds tongue M g to the wheels
    cart = TowedLoad(mass_kg=40.0, crr=0.05, hitch_xyz_m=(-0.8, ROBOT.com_y_m, 0.3), tongue_fraction=0.1)
    sc = straight("pavement", speed_mps=0.5, duration_s=6.0, brake=False)
    sim = Simulator(sc, seed=1, params=[tm.nominal_params("pavement")], towed=cart)
    res = sim.run()
    hitch = res.body_col("hitch")[res.t_s > 4.0].mean()
    assert hitch == pytest.approx(0.05 * 0.9 * 40.0 * 9.81, rel=0.05)
    assert res.wblock("load")[-1].sum() == pytest.approx(ROBOT.weight_n + 0.1 * 40.0 * 9.81, rel=0.02)
    sim.set_payload_kg(20.0)
    assert sim.ext[ph.E_MC] == 60.0


def test_a_stalled_wheel_never_digs_deeper_than_its_radius():
    """No control, dry sand, a cart the soil cannot pull: the wheels spin in place for 25 s. The
    dug depth stays bounded by the wheel radius and the state stays finite (it used to diverge)."""
    robot = load_robot()
    sim = Simulator(straight("dry_sand", 1.0, 25.0), robot, seed=5001,
                    towed=TowedLoad(mass_kg=80.0, crr=0.15, hitch_xyz_m=(-0.3, -0.25, 0.3)))
    res = sim.run()
    assert np.isfinite(res.log).all()
    dig = res.wblock("sinkage") - res.wblock("sinkage").min(axis=0)
    assert res.wblock("sinkage").max() <= robot.wheel_radius_m + 0.1   # dig <= R plus the static sinkage
    assert dig.max() > 0.05                      # it does dig in: the stall is real
    assert abs(res.body_col("x")[-1]) < 1.0       # and the robot stays stuck
