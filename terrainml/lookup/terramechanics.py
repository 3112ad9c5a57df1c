"""Wheel-terrain force curves of the terrain classes (design §6.1-6.2), nominal values from the catalogue.

The simulator (:mod:`terrainml.sim`) and the desired-slip lookup (:mod:`terrainml.lookup.table`) both
import this module; it imports neither.

Conventions
-----------
* ``slip`` is the SAE split slip of thesis eq. 7.1-7.2 / design §7.1, in [-1, 1]: positive in
  traction (wheel faster than the ground), negative in braking. Braking uses the same curves by
  symmetry: the thrust of braking slip ``-s`` is ``-H(s)`` and the sinkage (hence the motion
  resistance) depends on ``|s|``.
* ``gross_thrust_n`` is the signed soil/tyre shear force H (N) along the wheel heading; its torque
  on the wheel is ``R_wheel * H``.
* ``motion_resistance_n`` is the magnitude R >= 0 (N) of the resistance (rolling resistance,
  Bekker compaction) that opposes the wheel-centre motion.
* Net force on the vehicle along the wheel heading, forward motion: ``H - R``; hence
  ``mu_net = (H - R) / W``. The simulator's wheel spin equation ``J dw/dt = tau - R_w F_x - tau_rr``
  with ``F_x = H - R`` and ``tau_rr = R_w R`` is the same thing written as ``tau - R_w H``.

Force models (design §6.2)
--------------------------
``burckhardt`` (pavement)
    ``H = W [c1 (1 - exp(-c2 s)) - c3 s]``, ``R = C_rr W``.
``soil`` (all other classes)
    sinkage: Bekker rigid-wheel sinkage ``z0`` (classes with ``k_phi > 0``) or a fixed layer depth
    (``layer_depth_m``: the loose layer of gravel, the sod / vegetation mat, the soft crust of
    compacted dirt); slip-sinkage ``z(s) = z0 (1 + a s) / (1 - 0.5 a s)`` with ``a = slip_sinkage``;
    contact length ``L = sqrt(2 R z) + tyre_flat``, ``A = b L``;
    thrust ``H = (A c + W tan phi) * S(s' L / K)``, ``s' = max(|s| - s_f, 0) / (1 - s_f)`` (free slip
    ``s_f``), with the shear-curve average ``S`` of either
    Janosi-Hanamoto (``residual_ratio == 1``: ``S(x) = 1 - (1 - exp(-x)) / x``) or Wong's hump-type
    curve for compact / root-bound soils (``residual_ratio < 1``: peak shear stress at shear
    displacement K, residual ``K_r`` of it at large displacement);
    resistance: Bekker compaction ``R_c = (k_c + b k_phi) z^(n+1) / (n+1)`` plus ``C_rr W`` (tyre
    and wet-layer losses; 0 for the built-in classes) for Bekker classes, or ``C_rr W z(s) / z0`` for
    layer classes.

Departures from design §6.1 (recorded, with the reasons)
-------------------------------------------------------
* ``compacted_dirt``: the Burckhardt-type curve (c1 0.9, c2 12, c3 0.3) with C_rr 0.03 has its
  zero of mu_net at s = 0.003, far below the 0.02-0.05 target; no Burckhardt curve with a physical
  peak (mu > 0.5 at s 0.1-0.2) can put it there. It is modelled as a compact soil (hump-type shear
  on a thin crust over a firm base, C_rr 0.03); its traction peak stays in 0.10-0.20.
* All soil classes use Wong's hump-type shear curve (grass roots tear, gravel rolls over the firm
  base, loose soils dilate) instead of plain Janosi-Hanamoto, which on a 16 cm wheel has no interior
  peak (design §6.2 note); c, phi and the Bekker values of §6.1 are kept.
* Every soil has a *free slip* s_f: the slip taken up by the compressible top layer (vegetation mat,
  loose stones, soft crust or loose soil) before the firm layer is sheared (the "physiological free
  slip" of thesis §7.2.3). Without it, a steady slip of 12% with 6% motion resistance forces a K so
  large that the traction peak moves beyond s = 1.
* Slip-sinkage: the Lyasko-type factor of §6.2 is applied with a per-class gain ``a`` (``a = 1``
  is §6.2 exactly); with ``a = 1`` the Bekker compaction (~z^(n+1)) quadruples by s = 0.5 and no
  class could keep positive net traction.
* ``K`` (shear deformation modulus), ``s_f``, the layer depths, ``K_r`` and ``a`` were calibrated so that the root of
  mu_net(s) = 0 on the reference robot (80 kg, 3 wheels, R 0.165 m, b 0.09 m, tyre flat 0.03 m,
  equal loads 261.6 N) lies inside each class's §6.1 target; see ``benchmarks/sim_calibration.py``
  and the table in ``docs/sim.md``.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from scipy.optimize import brentq

from terrainml.classes import TERRAIN_CLASSES, class_id as _class_id
from terrainml.lookup.catalogue import load_catalogue
from terrainml.lookup.terrain_params import TerrainParams
from terrainml.robot import reference_robot

__all__ = [
    "TerrainParams", "nominal_params", "all_nominal_params", "sample_params",
    "sinkage_m", "contact_length_m", "gross_thrust_n", "motion_resistance_n", "lateral_force_n",
    "net_traction_coefficient", "steady_slip", "SPREAD_FIELDS",
]

# ----------------------------------------------------------------------------- class table
# The nominal values live once, in the reference terrain catalogue (lookup/catalogues/
# reference.yaml, every value with its source); calibrated values (K, layer depths, slip-sinkage
# gains, free slip) come from benchmarks/sim_calibration.py.
_NOMINAL: tuple[TerrainParams, ...] = tuple(
    replace(c.params, class_id=i) for i, c in enumerate(load_catalogue("reference").classes))
assert tuple(p.name for p in _NOMINAL) == TERRAIN_CLASSES

# parameters perturbed by sample_params (multiplicative, uniform in [1 - spread, 1 + spread])
SPREAD_FIELDS: tuple[str, ...] = (
    "c1", "crr", "cohesion_pa", "friction_angle_rad", "shear_modulus_m", "k_c", "k_phi",
    "layer_depth_m", "free_slip", "lateral_mu", "roughness_rms_m",
)


def nominal_params(class_id: int | str) -> TerrainParams:
    """Nominal parameters of a class (id or name), design §6.1 with the calibrated values."""
    return _NOMINAL[_class_id(class_id)]


def all_nominal_params() -> tuple[TerrainParams, ...]:
    """Nominal parameters of every class, in class-id order."""
    return _NOMINAL


def sample_params(class_id: int | str, rng: np.random.Generator, spread: float = 0.15) -> TerrainParams:
    """One run's terrain realisation: each field of :data:`SPREAD_FIELDS` scaled by U(1-spread, 1+spread).

    The spread is a fraction (0.15 = ±15%, design §6.1 default). ``spread=0`` returns the nominal
    parameters. Classes overlap a little, as real soils do.
    """
    if not 0.0 <= spread < 1.0:
        raise ValueError(f"spread must be in [0, 1), got {spread}")
    p = nominal_params(class_id)
    if spread == 0.0:
        return p
    factors = rng.uniform(1.0 - spread, 1.0 + spread, size=len(SPREAD_FIELDS))
    return replace(p, **{name: getattr(p, name) * float(f) for name, f in zip(SPREAD_FIELDS, factors)})


# ----------------------------------------------------------------------------- geometry
def _robot_geom(robot) -> tuple[float, float, float]:
    if robot is None:
        robot = reference_robot()
    return float(robot.wheel_radius_m), float(robot.wheel_width_m), float(robot.tyre_flat_m)


def static_sinkage_m(p: TerrainParams, load_n, robot=None) -> np.ndarray:
    """Zero-slip sinkage z0 (m): Bekker rigid-wheel sinkage or the layer depth."""
    r_w, b, _ = _robot_geom(robot)
    w = np.maximum(np.asarray(load_n, dtype=float), 0.0)
    if p.is_bekker:
        n = p.n_exp
        k = p.k_c + b * p.k_phi
        return (3.0 * w / ((3.0 - n) * k * math.sqrt(2.0 * r_w))) ** (2.0 / (2.0 * n + 1.0))
    return np.full_like(w, p.layer_depth_m)


def _sinkage_factor(p: TerrainParams, slip) -> np.ndarray:
    a = p.slip_sinkage * np.minimum(np.abs(np.asarray(slip, dtype=float)), 1.0)
    return (1.0 + a) / (1.0 - 0.5 * a)


def sinkage_m(p: TerrainParams, load_n, slip, robot=None) -> np.ndarray:
    """Slip sinkage z(s) = z0 (1 + a|s|) / (1 - 0.5 a|s|) (m); 0 for the burckhardt model."""
    if p.model == "burckhardt":
        return np.zeros(np.broadcast(np.asarray(load_n), np.asarray(slip)).shape)
    return static_sinkage_m(p, load_n, robot) * _sinkage_factor(p, slip)


def contact_length_m(p: TerrainParams, sinkage, robot=None) -> np.ndarray:
    """Contact length L = sqrt(2 R z) + tyre flat (m)."""
    r_w, _, flat = _robot_geom(robot)
    return np.sqrt(2.0 * r_w * np.maximum(np.asarray(sinkage, dtype=float), 0.0)) + flat


# ----------------------------------------------------------------------------- shear curves
def _mean_exp(x: np.ndarray) -> np.ndarray:
    """(1 - exp(-x)) / x, with its limit 1 at x = 0."""
    safe = np.where(x > 1e-9, x, 1.0)
    return np.where(x > 1e-9, -np.expm1(-safe) / safe, 1.0 - 0.5 * x)


def _shear_fraction(p: TerrainParams, u: np.ndarray) -> np.ndarray:
    """Contact-patch average of tau / tau_max for shear displacement j = s x, u = s L / K (>= 0)."""
    if p.residual_ratio >= 1.0:
        return 1.0 - _mean_exp(u)                                     # Janosi-Hanamoto
    kr = p.residual_ratio
    c = 1.0 / (kr * (1.0 - math.exp(-1.0))) - 1.0                     # Wong hump-type
    g1 = _mean_exp(u)
    g2 = _mean_exp(2.0 * u)
    return kr * (1.0 - g1 + c * math.e * (g1 - g2))


def _shear_slip(p: TerrainParams, abs_slip: np.ndarray) -> np.ndarray:
    """Slip that shears the firm layer: (|s| - s_f) / (1 - s_f), 0 below the free slip s_f."""
    if p.free_slip <= 0.0:
        return abs_slip
    return np.maximum(abs_slip - p.free_slip, 0.0) / (1.0 - p.free_slip)


def gross_thrust_n(p: TerrainParams, load_n, slip, robot=None) -> np.ndarray:
    """Signed gross thrust H(s) (N) along the wheel heading; braking by symmetry H(-s) = -H(s).

    Parameters
    ----------
    p : terrain parameters.
    load_n : normal load W (N), scalar or array broadcastable with ``slip``.
    slip : SAE split slip in [-1, 1], any shape.
    robot : RobotSpec (wheel radius, width, tyre flat); the reference robot if None.
    """
    s = np.clip(np.asarray(slip, dtype=float), -1.0, 1.0)
    w = np.maximum(np.asarray(load_n, dtype=float), 0.0)
    a = np.abs(s)
    if p.model == "burckhardt":
        mu = p.c1 * (1.0 - np.exp(-p.c2 * a)) - p.c3 * a
        return np.sign(s) * mu * w
    _, b, _ = _robot_geom(robot)
    z = sinkage_m(p, w, a, robot)
    length = contact_length_m(p, z, robot)
    h_max = b * length * p.cohesion_pa + w * math.tan(p.friction_angle_rad)
    u = _shear_slip(p, a) * length / p.shear_modulus_m
    return np.sign(s) * h_max * _shear_fraction(p, u)


def motion_resistance_n(p: TerrainParams, load_n, slip, robot=None) -> np.ndarray:
    """Motion resistance R(s) >= 0 (N): rolling resistance or Bekker compaction at slip sinkage."""
    s = np.asarray(slip, dtype=float)
    w = np.maximum(np.asarray(load_n, dtype=float), 0.0)
    if p.model == "burckhardt":
        return np.broadcast_to(p.crr * w, np.broadcast(w, s).shape).astype(float)
    _, b, _ = _robot_geom(robot)
    if p.is_bekker:
        z = sinkage_m(p, w, s, robot)
        n = p.n_exp
        return (p.k_c + b * p.k_phi) * z ** (n + 1.0) / (n + 1.0) + p.crr * w
    return p.crr * w * _sinkage_factor(p, s)


def lateral_force_n(p: TerrainParams, load_n, slip_angle_rad, robot=None) -> np.ndarray:
    """Lateral force (N) along the wheel's left axis, opposing the slip angle.

    ``slip_angle_rad = atan2(v_lateral, |v_longitudinal|)`` of the wheel centre;
    ``F_y = -lateral_mu W tanh(alpha / lateral_alpha0)`` (saturates with slip angle).
    """
    w = np.maximum(np.asarray(load_n, dtype=float), 0.0)
    alpha = np.asarray(slip_angle_rad, dtype=float)
    return -p.lateral_mu * w * np.tanh(alpha / p.lateral_alpha0_rad)


def net_traction_coefficient(p: TerrainParams, load_n, slip, robot=None) -> np.ndarray:
    """mu_net(s) = (H(s) - R(s)) / W for forward motion (vectorised over slip in [-1, 1])."""
    w = np.maximum(np.asarray(load_n, dtype=float), 1e-9)
    return (gross_thrust_n(p, w, slip, robot) - motion_resistance_n(p, w, slip, robot)) / w


def steady_slip(p: TerrainParams, load_n: float, robot=None) -> float:
    """Root of mu_net(s) = 0 on (0, 1): the slip that keeps constant speed (NaN if none)."""
    def f(s: float) -> float:
        return float(net_traction_coefficient(p, load_n, s, robot))

    grid = np.linspace(0.0, 0.99, 991)
    vals = net_traction_coefficient(p, load_n, grid, robot)
    idx = np.flatnonzero((vals[:-1] <= 0.0) & (vals[1:] > 0.0))
    if len(idx) == 0:
        return float("nan")
    i = int(idx[0])
    return float(brentq(f, grid[i], grid[i + 1], xtol=1e-7))
