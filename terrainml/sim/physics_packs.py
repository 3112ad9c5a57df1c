"""The physics kernel's input packs (:mod:`terrainml.sim.physics`): the robot, the ground and the state.

:func:`terrainml.sim.physics.run_substeps` takes each pack as a plain tuple (``tuple(pack)``) and
rebuilds it inside the compiled code, which reads its fields by position. numba's on-disk cache
watches only the kernel's own file, so after reordering fields of the same type here, delete the
cache (``find terrainml -name '*.nbi' -delete``) or touch ``physics.py``; adding or removing a
field changes the tuple's type and recompiles by itself.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class Vehicle(NamedTuple):
    """Robot geometry, inertia and low-level control (constant over a run)."""

    wx: np.ndarray  # (N,) wheel contact x, body frame (m)
    wy: np.ndarray  # (N,) wheel contact y (m)
    xc: float  # centre of mass x, y (m)
    yc: float
    mass: float  # kg
    iz: float  # yaw inertia (kg m^2)
    rw: float  # wheel radius (m)
    jw: float  # wheel inertia (kg m^2)
    hcg: float  # centre-of-mass height (m)
    load_pinv: np.ndarray  # (N, 3) static load distribution: pinv of [1; x_i; y_i]
    kp: float  # wheel-speed PI gains (N m s/rad, N m/rad)
    ki: float
    tau_max: float  # torque (current) limit (N m)
    steer_rate_max: float  # rad/s
    steer_deadband: float  # rad
    steer_tau: float  # steering first-order approach (s)
    omega_lag_tau: float  # drive's reported-speed lag (s)
    dt: float  # substep (s)
    kt: float  # torque constant at the wheel (N m / A)
    r_ph: float  # equivalent phase resistance (ohm): copper loss (tau / kt)^2 r_ph
    eta_drv: float  # driver efficiency (motoring)
    eta_regen: float  # share of negative electrical power returned to the bus
    clearance: float  # ground clearance (m): belly drag past it
    belly_mu: float  # belly-on-soil drag coefficient and its ramp (m)
    belly_ramp: float


class Ground(NamedTuple):
    """Terrain of a run: per-cell force tables (terrain.py) and the layout grid."""

    h_tab: np.ndarray  # (cells, loads, slips) traction per reference load
    r_tab: np.ndarray  # (cells, loads, slips) motion resistance per reference load
    y_tab: np.ndarray  # (cells, alphas) lateral force per load
    hmax_tab: np.ndarray  # (cells, loads) traction peak per reference load
    w_ref: float  # reference load of the tables (N)
    load_grid: np.ndarray  # load factors of the tables' load axis
    alpha_lo: float  # first slip angle of y_tab (rad) and its step
    alpha_step: float
    rough_amp: np.ndarray  # (cells, K) roughness amplitudes (m), wavenumbers (rad/m), phases (N, K)
    rough_k: np.ndarray
    rough_phase: np.ndarray
    lay_grid: np.ndarray  # (nx, ny) layout cells; cell size and origin (m)
    lay_cell: float
    lay_ox: float
    lay_oy: float
    grad_x: np.ndarray  # (cells,) surface gradient tan(slope) along world x, y
    grad_y: np.ndarray
    len_tab: np.ndarray  # (cells, loads) contact length at zero slip (m)
    z_tab: np.ndarray  # (cells, loads, slips) slip sinkage z(s, W) (m)
    free_slip: np.ndarray  # (cells,) s_f
    dig_k: np.ndarray  # (cells,) kappa, relaxation length (m), cap (m) of the dig-in state
    dig_relax: np.ndarray
    dig_cap: np.ndarray
    cart_crr: np.ndarray  # (cells,) cart rolling resistance coefficient on each cell


class SimState(NamedTuple):
    """Arrays advanced in place (layouts in :mod:`terrainml.sim.physics`'s docstring)."""

    body: np.ndarray
    wheel: np.ndarray
    acc: np.ndarray
    log: np.ndarray
    ext: np.ndarray
