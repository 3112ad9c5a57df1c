"""Mission physics of the simulator (design §6, §6.2): grade, towed load and tool draft,
sinkage as a per-wheel state, thrust from accumulated shear displacement, battery energy.

This module holds the new laws' parameters and their steady-state ("truth") curves; the compiled
kernel (:mod:`terrainml.sim.physics`) integrates them. The API below is stable (missions build on it).

API
---
Terrain grade (``terrainml.sim.terrain``)::

    lay = TerrainLayout.patches(grid, cell_m=2.0)                  # as before
    lay = lay.with_grade(slope_x_rad=0.05, slope_y_rad=0.0)        # scalar or (nx, ny) grid
    lay = TerrainLayout(grid, cell_m, origin, slope_x_rad=sx, slope_y_rad=sy)
    lay.grade_at(x_m, y_m) -> (slope_x_rad, slope_y_rad)           # world-frame surface slopes

``slope_x_rad`` is the surface angle along world +x (the ground rises towards +x when positive),
``slope_y_rad`` along world +y. Positions x, y are read as distances along the surface.

Towed load and tool draft (``terrainml.sim.simulator``)::

    sim = Simulator(scenario, robot, seed, towed=TowedLoad(mass_kg=30.0, crr=0.08,
                    hitch_xyz_m=(-0.8, -0.252, 0.3)), tool_draft_n=0.0)
    sim.set_payload_kg(25.0)       # cart payload (kg, added to TowedLoad.mass_kg), between steps
    sim.set_tool_draft_n(120.0)    # soil-engaging tool's draft (N), between steps
    sim.payload_kg, sim.tool_draft_n

``TowedLoad.crr`` is a float or a mapping {class id or name: C_rr} (the terrain under the hitch).

Robot spec (``terrainml.robot``, new optional fields; defaults are documented assumptions)::

    ground_clearance_m: 0.10          # belly / axle clearance above the wheel contact (m)
    motor: {phase_resistance_ohm: 0.25, driver_efficiency: 0.95, regen_efficiency: 0.65}
    com_height_m                      # existing field: h_cg for pitch load transfer

Logs and results (``SimResult``; one row per 200 Hz log row)::

    res.body_col("pitch")      # (n,) grade under the robot along its heading, rad (nose up > 0)
    res.body_col("roll")       # (n,) grade across the heading, rad (left side up > 0)
    res.body_col("drawbar")    # (n,) drawbar pull DP = sum_i (H_i - R_i) cos(delta_i), N
    res.body_col("hitch")      # (n,) force the cart and tool pull back on the hitch, N (>= 0 when pulled)
    res.body_col("p_batt")     # (n,) battery power, W (negative while regenerating)
    res.body_col("p_mech")     # (n,) mechanical power at the wheels, sum tau omega, W
    res.wblock("sinkage")      # (n, N) total sinkage per wheel z = z_slip(s, W) + z_dig, m
    res.wblock("rut")          # (n, N) rut depth left behind each wheel (= sinkage, all plastic), m
    res.wblock("thrust")       # (n, N) gross thrust H per wheel, N (slip power H (omega R - v_long))
    res.wblock("slip_j")       # (n, N) shear-displacement slip j / L (equals the slip in steady state)
    res.battery_energy_j, res.battery_energy_noregen_j, res.copper_loss_j, res.slip_work_j,
    res.drawbar_work_j         # also in res.summary under the same names
    res.energy_j               # unchanged: mechanical energy at the wheels, sum tau omega dt

Steady-state truth for missions (demand ratio, oracle cap)::

    effective_net_traction(params, load_n, slip, robot)  # mu_net incl. the dig-in sinkage state
    traction_peak(params, load_n, robot) -> (slip, mu_net)

Assumptions and departures are listed in docs/sim.md ("Mission physics") and design §6, §6.2.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from terrainml.classes import N_CLASSES, class_id as _class_id
from terrainml.lookup import terramechanics as tm
from terrainml.robot import MotorSpec

__all__ = [
    "TowedLoad", "DigParams", "dig_params", "BELLY_MU", "BELLY_RAMP_M", "DEFAULT_GROUND_CLEARANCE_M",
    "DEFAULT_MOTOR", "steady_dig_sinkage_m", "effective_net_traction", "traction_peak",
    "cart_crr_per_class",
]

DEFAULT_GROUND_CLEARANCE_M = 0.10   # assumption: belly 10 cm above the contact (wheel R 0.165 m)
# assumption: hub-motor drive, equivalent phase resistance (copper loss I^2 R with I = tau / k_t),
# driver (inverter) efficiency, and the share of negative electrical power returned to the bus
DEFAULT_MOTOR = MotorSpec()
BELLY_MU = 0.5                      # assumption: belly-on-soil sliding coefficient
BELLY_RAMP_M = 0.02                 # assumption: belly drag reaches BELLY_MU W within 2 cm past clearance


@dataclass(frozen=True)
class TowedLoad:
    """A cart pulled at a hitch: empty mass, rolling resistance and hitch point (body frame).

    Parameters
    ----------
    mass_kg : cart mass without payload (kg); the payload is set with ``Simulator.set_payload_kg``.
    crr : rolling-resistance coefficient of the cart's wheels, a float or {class id/name: C_rr}
        for the terrain under the hitch (classes missing from the mapping use 0.05).
    hitch_xyz_m : hitch point in the body frame (m): x, y and height above the ground.
    tongue_fraction : share of the cart's weight carried by the hitch (vertical load on the robot).
    payload_kg : initial payload (kg).
    """

    mass_kg: float
    crr: float | Mapping = 0.05
    hitch_xyz_m: tuple[float, float, float] = (-0.8, 0.0, 0.3)
    tongue_fraction: float = 0.1
    payload_kg: float = 0.0

    def __post_init__(self):
        if self.mass_kg < 0 or self.payload_kg < 0:
            raise ValueError("TowedLoad: mass_kg and payload_kg must be >= 0")
        if not 0.0 <= self.tongue_fraction < 1.0:
            raise ValueError(f"TowedLoad: tongue_fraction must be in [0, 1), got {self.tongue_fraction}")
        if len(self.hitch_xyz_m) != 3:
            raise ValueError("TowedLoad: hitch_xyz_m must be (x, y, z)")


def cart_crr_per_class(crr: float | Mapping) -> np.ndarray:
    """(N_CLASSES,) cart rolling-resistance coefficient per terrain class."""
    if isinstance(crr, Mapping):
        out = np.full(N_CLASSES, 0.05)
        for k, val in crr.items():
            out[_class_id(k)] = float(val)
        return out
    return np.full(N_CLASSES, float(crr))


@dataclass(frozen=True)
class DigParams:
    """Excavation (dig-in) sinkage of one soil: a per-wheel state z_dig (m).

    dz_dig/dt = (kappa z0 s'^2 max(|omega R|, |v|) - z_dig |v|) / relax_m,  0 <= z_dig <= cap_m

    z0 static sinkage at the wheel's load, s' the shear slip past the free slip (design §6.2, D9):
    excavation needs the firm layer to shear, and grows faster than linearly with it (Lyasko's
    factor is convex in slip). Steady state (traction): z_dig = kappa z0 s'^2 / (1 - s); at a stall
    (v = 0) there is none: the wheel digs itself in at kappa z0 |omega R| / relax_m. Driving on, the
    extra depth relaxes over ``relax_m`` of travel; lifting the load W out of the rut over that
    length costs the motion resistance ``W z_dig / relax_m`` (the relaxation term's rise rate
    times W, per metre). ``kappa`` is set so that the steady total
    sinkage at s = 0.8 equals the Lyasko-type factor at the strength the literature supports
    (``_A_LIT``), the force tables keeping their calibrated gain a (D10).
    """

    kappa: float
    relax_m: float
    cap_m: float


# Lyasko-type slip-sinkage strength the literature supports per class (Lyasko 2010; Reece 1965:
# slip-sinkage dominates on dry sand, is weaker on cohesive soils and is bounded by the firm base
# under thin layers). a_lit = 1 is the full z0 (1 + s)/(1 - 0.5 s).
_A_LIT = (0.0, 0.5, 0.6, 0.6, 0.6, 0.8, 1.0, 0.8)
RELAX_M = 0.25                      # assumption: a rut's extra depth relaxes over ~1.5 wheel radii
_S_REF = 0.8                        # slip where the full-strength factor is matched
_DIG_EXP = 2.0                      # excavation rate ~ s'^2


def _lyasko(a: float, s: float) -> float:
    return (1.0 + a * s) / (1.0 - 0.5 * a * s)


def _dig_params_nominal(cid: int) -> DigParams:
    p = tm.nominal_params(cid)
    if p.model == "burckhardt":
        return DigParams(0.0, RELAX_M, 0.0)
    extra = max(_lyasko(_A_LIT[cid], _S_REF) - _lyasko(p.slip_sinkage, _S_REF), 0.0)
    s_shear = max(_S_REF - p.free_slip, 0.0) / (1.0 - p.free_slip)
    kappa = extra * (1.0 - _S_REF) / s_shear ** _DIG_EXP if s_shear > 0 else 0.0
    # thin layers on a firm base: the wheel cannot dig far below the loose layer
    cap = math.inf if p.is_bekker else 3.0 * p.layer_depth_m
    return DigParams(float(kappa), RELAX_M, float(cap))


_DIG = tuple(_dig_params_nominal(c) for c in range(N_CLASSES))


def dig_params(class_id: int | str) -> DigParams:
    """Dig-in parameters of a class (id or name)."""
    return _DIG[_class_id(class_id)]


def steady_dig_sinkage_m(p: tm.TerrainParams, load_n, slip, robot=None) -> np.ndarray:
    """Steady excavation sinkage z_dig (m) at a constant traction slip in [0, 1) (DigParams)."""
    d = dig_params(p.class_id)
    s = np.clip(np.abs(np.asarray(slip, dtype=float)), 0.0, 0.999)
    z0 = tm.static_sinkage_m(p, load_n, robot) if p.model != "burckhardt" else np.zeros_like(s)
    s_sh = np.maximum(s - p.free_slip, 0.0) / (1.0 - p.free_slip)
    return np.minimum(d.kappa * z0 * s_sh ** _DIG_EXP / (1.0 - s), d.cap_m)


def effective_net_traction(p: tm.TerrainParams, load_n, slip, robot=None) -> np.ndarray:
    """Steady mu_net(s) the simulator reaches on level ground, dig-in sinkage included.

    (H(s) - R(s) - W z_dig(s) / relax_m) / W, without belly drag (z below clearance).
    """
    s = np.asarray(slip, dtype=float)
    w = max(float(load_n), 1e-9)
    h = tm.gross_thrust_n(p, w, s, robot)
    r = tm.motion_resistance_n(p, w, s, robot)
    r = r + w * steady_dig_sinkage_m(p, w, s, robot) / dig_params(p.class_id).relax_m
    return (h - r) / w


def traction_peak(p: tm.TerrainParams, load_n: float, robot=None) -> tuple[float, float]:
    """(slip, mu_net) at the peak of :func:`effective_net_traction` on (0, 0.99]."""
    s = np.linspace(0.0, 0.99, 991)
    mu = effective_net_traction(p, load_n, s, robot)
    i = int(np.argmax(mu))
    return float(s[i]), float(mu[i])
