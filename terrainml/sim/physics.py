"""Compiled physics kernel: planar rigid body + N wheels, wheel-terrain forces, PI wheel drives,
grade, a towed cart and tool draft, sinkage and shear displacement as per-wheel states, battery power.

Integration: semi-implicit (symplectic) Euler at ``dt`` (default 1 ms). The tyre/soil contact is
stiff at low speed (dF/d(slip velocity) ~ k / v), so each contact force gets a linearly implicit
correction (Rosenbrock-Euler with a per-contact diagonal Jacobian: wheel inertia J/R^2 and the
wheel's share of the body mass; slope = max(local, secant to the predicted slip)): the fixed
points (steady slip, steady turns) are those of the explicit model, only the stiff transient is
damped. The lateral slip angle uses ``max(|v_long|, 0.25 m/s)`` in its denominator (low-speed
tyre regularisation).

Mission physics (design §6.2; equations in docs/sim.md "Mission physics", parameters in
:mod:`terrainml.sim.mission_physics`): thrust from the accumulated shear displacement (a state per
wheel), sinkage with a dig-in state, grade and load transfer, a towed cart and tool draft, and the
battery power of the wheel drives.

Inputs are packed: :class:`Vehicle` (robot and drive gains), :class:`Ground` (terrain tables
and layout), :class:`SimState` (arrays below). :func:`run_substeps` takes them as plain tuples
(``tuple(pack)``) and rebuilds the named tuples inside: numba types a plain tuple in C, a
``NamedTuple`` in Python (microseconds a call). The two steps LLVM does not inline itself are
inlined by numba (``inline="always"``): a call would copy the packs by value. A substep is a
sequence of named steps: steering rates, kinematics and loads, longitudinal and lateral forces,
drive torques, friction ellipse, body forces, implicit contact corrections, integration, log.

State layout (float64 arrays, mutated in place)
-----------------------------------------------
body  : [X, Y, psi, u, w, r, ax_cm, ay_cm, r_dot, f_hitch]  (CoM velocity u, w in body axes;
        ax/ay inertial CoM acceleration in body axes; previous-step values used for load transfer;
        f_hitch: previous hitch force along body x, N, negative when the cart pulls back)
wheel : (N_WROWS, N) rows omega, delta, integ (PI integrator, N m), omega_filt (drive's reported
        speed, first-order lag), dist (m travelled, roughness), tau (motor torque), load (N),
        s_j (shear-displacement slip j / L), z_dig (dig-in sinkage, m), z (total sinkage, m),
        thrust (gross thrust H, N)
acc   : ACC names: mechanical energy at the wheels, distance, time, battery energy (with
        regeneration; without: only positive bus power), copper loss, slip work, drawbar work
ext   : EXT names: settable between steps (cart mass, tongue share, hitch x y z, tool draft)

Uses numba when installed (``pip install numba``); otherwise runs the same code as plain Python
(slow, ~50x real time less). ``HAVE_NUMBA`` tells which.
"""

from __future__ import annotations

import math

import numpy as np

from terrainml._numba import HAVE_NUMBA, njit  # noqa: F401  (HAVE_NUMBA re-exported)
from terrainml.sim.physics_packs import Ground, SimState, Vehicle

G = 9.81
B_X, B_Y, B_PSI, B_U, B_W, B_R, B_AX, B_AY, B_RDOT, B_FH = range(10)
N_BODY = 10
W_OMEGA, W_DELTA, W_INTEG, W_OFILT, W_DIST, W_TAU, W_LOAD, W_SJ, W_DIG, W_Z, W_H = range(11)
N_WROWS = 11
ACC = ("energy_mech_j", "distance_m", "time_s", "battery_j", "battery_noregen_j", "copper_loss_j",
       "slip_work_j", "drawbar_work_j")
A_EMECH, A_DIST, A_TIME, A_BATT, A_BATT_NR, A_CU, A_SLIPW, A_DPW = range(8)
EXT = ("cart_mass_kg", "tongue_fraction", "hitch_x_m", "hitch_y_m", "hitch_z_m", "tool_draft_n")
E_MC, E_TONGUE, E_HX, E_HY, E_HZ, E_DRAFT = range(6)
# log columns (one row per logged substep): pitch / roll (rad) of the grade under the robot,
# drawbar pull (N), hitch force (N, >= 0 when the cart and tool pull back), battery and
# mechanical power (W)
LOG_COLS = ("t", "x", "y", "psi", "vx", "vy", "r", "ax", "ay", "rdot", "az",
            "pitch", "roll", "drawbar", "hitch", "p_batt", "p_mech")
(L_T, L_X, L_Y, L_PSI, L_VX, L_VY, L_R, L_AX, L_AY, L_RDOT, L_AZ,
 L_PITCH, L_ROLL, L_DP, L_HITCH, L_PBATT, L_PMECH) = range(17)
# per-wheel log blocks (each N wide), after the body columns
WLOG = ("omega", "omega_filt", "delta", "tau", "v_long", "v_lat", "load", "cell",
        "sinkage", "rut", "thrust", "slip_j")
N_LOG_BODY = len(LOG_COLS)

L_MIN = 0.01   # m: floor of the contact length of the shear-displacement state


# per-wheel work array of one substep, (N_CROWS, N): one row per quantity (a 2-D array rather
# than a tuple of arrays: numba updates a reference count at every read of a tuple's array)
(C_HH,       # longitudinal (traction) force (N): from the tables, friction-limited, then corrected
 C_HRAW,     # traction from the tables before the ellipse (N)
 C_KD,       # unused (the longitudinal force is a state)
 C_RR,       # motion resistance (N)
 C_HMAX,     # traction peak at this load (N)
 C_FYL,      # lateral force (N)
 C_KY,       # -dF_y / d(v_lat) >= 0
 C_COS,      # cos, sin of the steering angle
 C_SIN,
 C_VLONG,    # wheel-centre velocity along / across the wheel (m/s)
 C_VLAT,
 C_DDELTA,   # steering rate (rad/s)
 C_CELL,     # layout cell under the wheel (an integer, stored as float)
 C_DEN,      # unused
 C_SLIP,
 C_LOADIDX,  # fractional load index of the tables
 C_FX,       # force in body axes (N)
 C_FY,
 C_ZSLIP) = range(19)  # slip sinkage z(s_j, W) from the table (m)
N_CROWS = 19
# per-substep scalars (grade, hitch, powers)
(S_GBX, S_GBY, S_GBZ, S_PITCH, S_ROLL, S_CELL0, S_HCELL, S_DP, S_HITCH, S_PB, S_PM) = range(11)
N_SROWS = 11


@njit(cache=True, inline="always")
def _grid_cell(idx_f, n):
    """Lower node and fraction of a fractional index on a grid of ``n`` nodes, clamped to the grid
    (the last cell takes the end point, fraction 1)."""
    if idx_f < 0.0:
        idx_f = 0.0
    if idx_f > n - 1.0:
        idx_f = n - 1.0
    i = int(idx_f)
    if i >= n - 1:
        i = n - 2
    return i, idx_f - i


@njit(cache=True)
def _interp_table(tab, c, lf, s_idx_f, n_load, n_slip):
    """Bilinear interpolation of tab[c, load, slip]; returns value and d/d(slip index)."""
    if lf < 0.0:
        lf = 0.0
    # LOAD_FACTORS are not uniform: the caller passes the fractional load index
    il = int(lf)
    if il >= n_load - 1:
        il = n_load - 2
    fl = lf - il
    if fl > 1.0:
        fl = 1.0
    i, fs = _grid_cell(s_idx_f, n_slip)
    a0 = tab[c, il, i] * (1.0 - fl) + tab[c, il + 1, i] * fl
    a1 = tab[c, il, i + 1] * (1.0 - fl) + tab[c, il + 1, i + 1] * fl
    return a0 + (a1 - a0) * fs, a1 - a0


@njit(cache=True)
def _load_index(load_factor, load_grid):
    n = load_grid.shape[0]
    if load_factor <= load_grid[0]:
        return 0.0
    for j in range(n - 1):
        if load_factor <= load_grid[j + 1]:
            return j + (load_factor - load_grid[j]) / (load_grid[j + 1] - load_grid[j])
    return n - 1.0


# Each step below loops over the wheels and first binds the arrays it uses to local names: an
# array read from a tuple field inside a loop costs numba a reference-count update per read.
@njit(cache=True, inline="always")
def _steering_rates(v, delta_cmd, wheel, ct):
    """Steering actuators: rate limit, dead band, first-order approach to the command."""
    for i in range(ct.shape[1]):
        err = delta_cmd[i] - wheel[W_DELTA, i]
        if abs(err) <= v.steer_deadband:
            ct[C_DDELTA, i] = 0.0
        else:
            d = err / v.steer_tau
            if d > v.steer_rate_max:
                d = v.steer_rate_max
            elif d < -v.steer_rate_max:
                d = -v.steer_rate_max
            ct[C_DDELTA, i] = d


@njit(cache=True)
def _cell_at(ox, oy, cell, nx, ny, px, py):
    """Layout cell (flat index) of a world point, clamped to the grid (scalars: a Ground pack
    passed to a call that is not inlined would be copied)."""
    ix = min(max(int(math.floor((px - ox) / cell)), 0), nx - 1)
    iy = min(max(int(math.floor((py - oy) / cell)), 0), ny - 1)
    return ix * ny + iy


@njit(cache=True, inline="always")
def _grade(g, body, ext, cpsi, spsi, sc):
    """Grade under the body origin: gravity along the surface in body axes (gbx, gby), normal
    gravity gbz = g cos(theta), pitch / roll of the surface; the cell under the hitch."""
    nx = g.lay_grid.shape[0]
    ny = g.lay_grid.shape[1]
    c = _cell_at(g.lay_ox, g.lay_oy, g.lay_cell, nx, ny, body[B_X], body[B_Y])
    gx = g.grad_x[c]
    gy = g.grad_y[c]
    nrm = math.sqrt(1.0 + gx * gx + gy * gy)
    # downhill acceleration along the surface, magnitude g sin(theta), world axes
    agx = -G * gx / nrm
    agy = -G * gy / nrm
    sc[S_GBX] = cpsi * agx + spsi * agy
    sc[S_GBY] = -spsi * agx + cpsi * agy
    sc[S_GBZ] = G / nrm
    sc[S_PITCH] = cpsi * gx + spsi * gy           # tangents; the log takes the angles
    sc[S_ROLL] = -spsi * gx + cpsi * gy
    sc[S_CELL0] = c
    sc[S_HCELL] = _cell_at(g.lay_ox, g.lay_oy, g.lay_cell, nx, ny, body[B_X] + cpsi * ext[E_HX] - spsi * ext[E_HY],
                           body[B_Y] + spsi * ext[E_HX] + cpsi * ext[E_HY])


@njit(cache=True, inline="always")
def _kinematics_and_loads(v, g, body, wheel, ext, cpsi, spsi, ct, sc):
    """Per wheel: layout cell under the contact, velocity along / across the wheel, and load:
    normal gravity plus the hitch's tongue load, load transfer from the pitch / roll moments of
    gravity along the grade, the previous accelerations and the hitch force, scaled by the
    roughness's vertical acceleration. Returns the wheels' mean vertical acceleration (m/s^2)."""
    wx, wy, load_pinv = v.wx, v.wy, v.load_pinv
    rough_amp, rough_k, rough_phase = g.rough_amp, g.rough_k, g.rough_phase
    ox, oy, cell = g.lay_ox, g.lay_oy, g.lay_cell
    nx = g.lay_grid.shape[0]
    ny = g.lay_grid.shape[1]
    n = wx.shape[0]
    u = body[B_U]
    w = body[B_W]
    r = body[B_R]
    m = v.mass
    tongue = ext[E_TONGUE] * ext[E_MC] * sc[S_GBZ]
    # sum N = m g_z + V;  sum N x = m g_z x_c - m (a_x - g_x) h + z_h F_hx + x_h V;  likewise y
    b1 = m * sc[S_GBZ] + tongue
    b2 = (m * sc[S_GBZ] * v.xc - m * (body[B_AX] - sc[S_GBX]) * v.hcg + ext[E_HZ] * body[B_FH]
          + ext[E_HX] * tongue)
    b3 = m * sc[S_GBZ] * v.yc - m * (body[B_AY] - sc[S_GBY]) * v.hcg + ext[E_HY] * tongue
    az_mean = 0.0
    for i in range(n):
        ld = load_pinv[i, 0] * b1 + load_pinv[i, 1] * b2 + load_pinv[i, 2] * b3
        c = _cell_at(ox, oy, cell, nx, ny, body[B_X] + cpsi * wx[i] - spsi * wy[i],
                     body[B_Y] + spsi * wx[i] + cpsi * wy[i])
        ct[C_CELL, i] = c
        vxi = u - r * (wy[i] - v.yc)
        vyi = w + r * (wx[i] - v.xc)
        speed2 = vxi * vxi + vyi * vyi
        zdd = 0.0
        for k in range(rough_k.shape[1]):
            zdd -= rough_amp[c, k] * rough_k[c, k] * rough_k[c, k] * math.sin(
                rough_k[c, k] * wheel[W_DIST, i] + rough_phase[i, k])
        zdd *= speed2
        az_mean += zdd / n
        f = 1.0 + zdd / G
        if f < 0.0:
            f = 0.0
        ld = ld * f
        if ld < 0.0:
            ld = 0.0
        wheel[W_LOAD, i] = ld
        de = wheel[W_DELTA, i]
        ct[C_COS, i] = math.cos(de)
        ct[C_SIN, i] = math.sin(de)
        ct[C_VLONG, i] = vxi * ct[C_COS, i] + vyi * ct[C_SIN, i]
        ct[C_VLAT, i] = -vxi * ct[C_SIN, i] + vyi * ct[C_COS, i]
    return az_mean


@njit(cache=True, inline="always")
def _longitudinal_forces(v, g, wheel, ct):
    """Per wheel: traction from the tables at the wheel's shear-displacement slip s_j and load,
    motion resistance (plus the climb out of the dug rut and belly drag past the clearance) and the
    traction peak at this load."""
    h_tab, r_tab, hmax_tab, z_tab, load_grid = g.h_tab, g.r_tab, g.hmax_tab, g.z_tab, g.load_grid
    w_ref = g.w_ref
    n_load = h_tab.shape[1]
    n_slip = h_tab.shape[2]
    s_scale = (n_slip - 1) / 2.0
    for i in range(ct.shape[1]):
        c = int(ct[C_CELL, i])
        s = wheel[W_SJ, i]
        if s > 1.0:
            s = 1.0
        elif s < -1.0:
            s = -1.0
        lf = _load_index(wheel[W_LOAD, i] / w_ref, load_grid)
        sf = (s + 1.0) * s_scale
        hv, hd = _interp_table(h_tab, c, lf, sf, n_load, n_slip)
        rv, rd = _interp_table(r_tab, c, lf, sf, n_load, n_slip)
        zv, zd = _interp_table(z_tab, c, lf, sf, n_load, n_slip)
        zdig = wheel[W_DIG, i]
        # climbing out of the dug rut: lifting W by z_dig over the relaxation length
        rv += wheel[W_LOAD, i] / w_ref * zdig / g.dig_relax[c]
        ztot = zv + zdig
        if ztot > v.clearance:
            rv += v.belly_mu * wheel[W_LOAD, i] / w_ref * min((ztot - v.clearance) / v.belly_ramp, 1.0)
        wheel[W_Z, i] = ztot
        ct[C_ZSLIP, i] = zv
        ct[C_HH, i] = hv * w_ref
        ct[C_HRAW, i] = ct[C_HH, i]
        ct[C_SLIP, i] = s
        ct[C_LOADIDX, i] = lf
        ct[C_RR, i] = rv * w_ref * math.tanh(ct[C_VLONG, i] / 0.02)
        il = int(lf)
        if il >= n_load - 1:
            il = n_load - 2
        fl = lf - il
        ct[C_HMAX, i] = (hmax_tab[c, il] * (1.0 - fl) + hmax_tab[c, il + 1] * fl) * w_ref


@njit(cache=True, inline="always")
def _lateral_forces(g, wheel, ct):
    """Per wheel: lateral force from the slip angle (table per unit load) and its slope."""
    y_tab = g.y_tab
    n_alpha = y_tab.shape[1]
    for i in range(ct.shape[1]):
        ld = wheel[W_LOAD, i]
        alpha = math.atan2(ct[C_VLAT, i], max(abs(ct[C_VLONG, i]), 0.25))
        af = (alpha - g.alpha_lo) / g.alpha_step
        ia, fa = _grid_cell(af, n_alpha)
        y0 = y_tab[int(ct[C_CELL, i]), ia]
        y1 = y_tab[int(ct[C_CELL, i]), ia + 1]
        ct[C_FYL, i] = (y0 + (y1 - y0) * fa) * ld
        dalpha_dv = 1.0 / max(abs(ct[C_VLONG, i]), 0.25) / (1.0 + alpha * alpha)
        ct[C_KY, i] = -(y1 - y0) / g.alpha_step * ld * dalpha_dv     # -dF_y/dv_lat >= 0


@njit(cache=True, inline="always")
def _drive_torques(v, wheel, omega_cmd):
    """PI wheel-speed drives with their current (torque) limit; the integrator holds while the
    output saturates and is clamped to the limit."""
    tau_max = v.tau_max
    for i in range(omega_cmd.shape[0]):
        e = omega_cmd[i] - wheel[W_OMEGA, i]
        tau = v.kp * e + wheel[W_INTEG, i]
        if tau > tau_max:
            tau = tau_max
        elif tau < -tau_max:
            tau = -tau_max
        else:
            wheel[W_INTEG, i] += v.ki * e * v.dt
        if wheel[W_INTEG, i] > tau_max:
            wheel[W_INTEG, i] = tau_max
        elif wheel[W_INTEG, i] < -tau_max:
            wheel[W_INTEG, i] = -tau_max
        wheel[W_TAU, i] = tau


@njit(cache=True, inline="always")
def _friction_ellipse(g, wheel, ct):
    """Combined slip: scale traction and lateral force back onto the friction ellipse."""
    y_tab = g.y_tab
    for i in range(ct.shape[1]):
        lat_max = abs(y_tab[int(ct[C_CELL, i]), 0]) * wheel[W_LOAD, i]
        if ct[C_HMAX, i] > 1e-9 and lat_max > 1e-9:
            rho = (ct[C_HH, i] / ct[C_HMAX, i]) ** 2 + (ct[C_FYL, i] / lat_max) ** 2
            if rho > 1.0:
                q = 1.0 / math.sqrt(rho)
                ct[C_HH, i] *= q
                ct[C_FYL, i] *= q


@njit(cache=True, inline="always")
def _body_forces(v, ct):
    """Wheel forces in body axes (into rows C_FX, C_FY of ``ct``); returns their sum and their yaw
    moment about the centre of mass."""
    wx, wy = v.wx, v.wy
    sfx = 0.0
    sfy = 0.0
    mz = 0.0
    for i in range(ct.shape[1]):
        fl_ = ct[C_HH, i] - ct[C_RR, i]
        ct[C_FX, i] = fl_ * ct[C_COS, i] - ct[C_FYL, i] * ct[C_SIN, i]
        ct[C_FY, i] = fl_ * ct[C_SIN, i] + ct[C_FYL, i] * ct[C_COS, i]
        sfx += ct[C_FX, i]
        sfy += ct[C_FY, i]
        mz += (wx[i] - v.xc) * ct[C_FY, i] - (wy[i] - v.yc) * ct[C_FX, i]
    return sfx, sfy, mz


@njit(cache=True, inline="always")
def _implicit_corrections(v, g, wheel, ud, wd, rdot, ct):
    """Linearly implicit correction of each lateral contact force (module docstring), given the
    explicit body accelerations ``ud, wd, rdot``. The longitudinal force is a state (shear
    displacement), so it needs none."""
    wx, wy = v.wx, v.wy
    dt = v.dt
    m_i = v.mass / wx.shape[0]
    for i in range(ct.shape[1]):
        dxi = wx[i] - v.xc
        dyi = wy[i] - v.yc
        aix = ud - rdot * dyi
        aiy = wd + rdot * dxi
        dvt = -aix * ct[C_SIN, i] + aiy * ct[C_COS, i] - ct[C_VLONG, i] * ct[C_DDELTA, i]
        bt = 1.0 / m_i + (dxi * dxi + dyi * dyi) / v.iz
        kyy = ct[C_KY, i]
        if kyy > 0.0:
            ct[C_FYL, i] -= kyy * dt * dvt / (1.0 + kyy * dt * bt)


@njit(cache=True, inline="always")
def _towed_x(v, g, body, ext, sfx, sc):
    """CoM acceleration along body x with gravity along the grade and the towed cart (moving
    with the body: its mass adds to the x inertia) and tool draft; returns it and the hitch force
    on the robot along body x (N, negative when pulled back)."""
    mc = ext[E_MC]
    dirn = math.tanh(body[B_U] / 0.02)          # resistances oppose the motion (as the wheels')
    rc = g.cart_crr[int(sc[S_HCELL])] * (1.0 - ext[E_TONGUE]) * mc * sc[S_GBZ] * dirn
    draft = ext[E_DRAFT] * dirn
    ax = (sfx + (v.mass + mc) * sc[S_GBX] - rc - draft) / (v.mass + mc)
    return ax, -mc * (ax - sc[S_GBX]) - rc - draft


@njit(cache=True, inline="always")
def _integrate(v, g, body, wheel, acc, cpsi, spsi, ax_cm, ay_cm, rdot, f_hitch, ct, sc):
    """Semi-implicit Euler: velocities from the final forces, then pose, wheel speeds, steering,
    shear displacement and dig-in sinkage states, distances, energies and powers. Returns the
    origin velocity (body axes).

    Numba kernel: takes the packs and the substep's scalars flat, because it is inlined into
    :func:`run_substeps` and a record of them would be built and copied every substep."""
    wx, wy = v.wx, v.wy
    len_tab, z_tab = g.len_tab, g.z_tab
    n_load = z_tab.shape[1]
    s_mid = (z_tab.shape[2] - 1) / 2.0
    dt = v.dt
    u = body[B_U]
    w = body[B_W]
    r = body[B_R]
    psi = body[B_PSI]
    body[B_U] = u + dt * (ax_cm + r * w)
    body[B_W] = w + dt * (ay_cm - r * u)
    body[B_R] = r + dt * rdot
    body[B_AX] = ax_cm
    body[B_AY] = ay_cm
    body[B_RDOT] = rdot
    body[B_FH] = f_hitch
    u2 = body[B_U]
    w2 = body[B_W]
    r2 = body[B_R]
    # origin velocity (body axes): v_o = v_cm + omega x (O - CM)
    vxo = u2 + r2 * v.yc
    vyo = w2 - r2 * v.xc
    body[B_X] += dt * (cpsi * vxo - spsi * vyo)
    body[B_Y] += dt * (spsi * vxo + cpsi * vyo)
    body[B_PSI] = psi + dt * r2
    p_bus = 0.0
    p_mech = 0.0
    p_cu = 0.0
    p_slip = 0.0
    dp = 0.0
    for i in range(wx.shape[0]):
        om = wheel[W_OMEGA, i]
        tau = wheel[W_TAU, i]
        hh = ct[C_HH, i]
        om2 = om + dt * (tau - v.rw * hh) / v.jw
        wheel[W_OMEGA, i] = om2
        wheel[W_H, i] = hh
        wheel[W_DELTA, i] += dt * ct[C_DDELTA, i]
        wheel[W_OFILT, i] += dt / v.omega_lag_tau * (om2 - wheel[W_OFILT, i])
        vxi = u2 - r2 * (wy[i] - v.yc)
        vyi = w2 + r2 * (wx[i] - v.xc)
        speed = math.sqrt(vxi * vxi + vyi * vyi)
        wheel[W_DIST, i] += dt * speed
        # shear displacement j = s_j L: dj/dt = (omega R - v) - j max(|omega R|, |v|) / L, exact
        # for the step (a first-order lag of the slip that holds still at standstill)
        vw = om2 * v.rw
        vl = vxi * ct[C_COS, i] + vyi * ct[C_SIN, i]
        mx = max(abs(vw), abs(vl))
        c = int(ct[C_CELL, i])
        lf = ct[C_LOADIDX, i]
        il = min(int(lf), n_load - 2)
        fl = min(lf - il, 1.0)
        length = max(len_tab[c, il] * (1.0 - fl) + len_tab[c, il + 1] * fl, L_MIN)
        if mx > 1e-12:
            f = -math.expm1(-mx * dt / length)
            wheel[W_SJ, i] += f * ((vw - vl) / mx - wheel[W_SJ, i])
        # dig-in sinkage: excavation ~ kappa z0 s'^2 while the firm layer shears, relaxation
        # over dig_relax metres of travel (terrainml.sim.mission_physics.DigParams)
        if g.dig_k[c] > 0.0:
            sf = g.free_slip[c]
            ssh = max(abs(wheel[W_SJ, i]) - sf, 0.0) / (1.0 - sf)
            z0, _ = _interp_table(z_tab, c, lf, s_mid, n_load, z_tab.shape[2])
            zd = wheel[W_DIG, i] + dt * (g.dig_k[c] * z0 * ssh * ssh * mx - wheel[W_DIG, i] * speed) / g.dig_relax[c]
            # a wheel cannot dig deeper than its own radius (the hub meets the ground; belly drag
            # has long taken over): without this bound a stalled wheel on loose sand digs without end
            wheel[W_DIG, i] = min(max(zd, 0.0), g.dig_cap[c], v.rw)
        pm = tau * om2
        cur = tau / v.kt
        pc = cur * cur * v.r_ph
        pe = pm + pc
        p_bus += pe / v.eta_drv if pe > 0.0 else pe * v.eta_regen
        p_mech += pm
        p_cu += pc
        p_slip += abs(hh * (vw - vl))
        dp += (hh - ct[C_RR, i]) * ct[C_COS, i]
    acc[A_EMECH] += dt * p_mech
    acc[A_DIST] += dt * math.sqrt(vxo * vxo + vyo * vyo)
    acc[A_TIME] += dt
    acc[A_BATT] += dt * p_bus
    acc[A_BATT_NR] += dt * max(p_bus, 0.0)
    acc[A_CU] += dt * p_cu
    acc[A_SLIPW] += dt * p_slip
    acc[A_DPW] += dt * (-f_hitch) * u2
    sc[S_DP] = dp
    sc[S_HITCH] = -f_hitch
    sc[S_PB] = p_bus
    sc[S_PM] = p_mech
    return vxo, vyo


@njit(cache=True, inline="always")
def _log(v, st, row, vxo, vyo, ax_cm, ay_cm, rdot, az_mean, ct, sc):
    """Write the truth log row ``row`` (columns: LOG_COLS, then the WLOG blocks).

    Numba kernel: takes the packs and the substep's scalars flat, because it is inlined into
    :func:`run_substeps` and a record of them would be built and copied every logged substep."""
    body, wheel, log, wx, wy = st.body, st.wheel, st.log, v.wx, v.wy
    n = wx.shape[0]
    u2 = body[B_U]
    w2 = body[B_W]
    r2 = body[B_R]
    log[row, L_T] = st.acc[2]
    log[row, L_X] = body[B_X]
    log[row, L_Y] = body[B_Y]
    log[row, L_PSI] = body[B_PSI]
    log[row, L_VX] = vxo
    log[row, L_VY] = vyo
    log[row, L_R] = r2
    # inertial acceleration of the origin (IMU), body axes
    log[row, L_AX] = ax_cm + rdot * v.yc + r2 * r2 * v.xc
    log[row, L_AY] = ay_cm - rdot * v.xc + r2 * r2 * v.yc
    log[row, L_RDOT] = rdot
    log[row, L_AZ] = az_mean
    log[row, L_PITCH] = math.atan(sc[S_PITCH])
    log[row, L_ROLL] = math.atan(sc[S_ROLL])
    log[row, L_DP] = sc[S_DP]
    log[row, L_HITCH] = sc[S_HITCH]
    log[row, L_PBATT] = sc[S_PB]
    log[row, L_PMECH] = sc[S_PM]
    base = N_LOG_BODY
    for i in range(n):
        vxi = u2 - r2 * (wy[i] - v.yc)
        vyi = w2 + r2 * (wx[i] - v.xc)
        de = wheel[W_DELTA, i]
        log[row, base + i] = wheel[W_OMEGA, i]
        log[row, base + n + i] = wheel[W_OFILT, i]
        log[row, base + 2 * n + i] = de
        log[row, base + 3 * n + i] = wheel[W_TAU, i]
        log[row, base + 4 * n + i] = vxi * math.cos(de) + vyi * math.sin(de)
        log[row, base + 5 * n + i] = -vxi * math.sin(de) + vyi * math.cos(de)
        log[row, base + 6 * n + i] = wheel[W_LOAD, i]
        log[row, base + 7 * n + i] = int(ct[C_CELL, i])
        log[row, base + 8 * n + i] = wheel[W_Z, i]
        log[row, base + 9 * n + i] = wheel[W_Z, i]
        log[row, base + 10 * n + i] = wheel[W_H, i]
        log[row, base + 11 * n + i] = wheel[W_SJ, i]


@njit(cache=True)
def run_substeps(vehicle, ground, state, n_sub, omega_cmd, delta_cmd, log_row, log_every):
    """Advance ``n_sub`` substeps; log every ``log_every``-th; return the next free log row.

    ``vehicle``, ``ground``, ``state``: the fields of :class:`Vehicle`, :class:`Ground`,
    :class:`SimState` as plain tuples. ``omega_cmd``, ``delta_cmd`` (N,): wheel-speed (rad/s)
    and steering (rad) set-points.
    """
    v, g, st = Vehicle(*vehicle), Ground(*ground), SimState(*state)
    body, wheel, ext = st.body, st.wheel, st.ext
    ct = np.empty((N_CROWS, v.wx.shape[0]))
    sc = np.zeros(N_SROWS)
    for step in range(n_sub):
        cpsi = math.cos(body[B_PSI])
        spsi = math.sin(body[B_PSI])
        _grade(g, body, ext, cpsi, spsi, sc)
        _steering_rates(v, delta_cmd, wheel, ct)
        az_mean = _kinematics_and_loads(v, g, body, wheel, ext, cpsi, spsi, ct, sc)
        _longitudinal_forces(v, g, wheel, ct)
        _lateral_forces(g, wheel, ct)
        _drive_torques(v, wheel, omega_cmd)
        _friction_ellipse(g, wheel, ct)
        sfx, sfy, mz = _body_forces(v, ct)  # explicit accelerations
        ud = sfx / v.mass + sc[S_GBX] + body[B_R] * body[B_W]
        wd = sfy / v.mass + sc[S_GBY] - body[B_R] * body[B_U]
        _implicit_corrections(v, g, wheel, ud, wd, mz / v.iz, ct)
        sfx, sfy, mz = _body_forces(v, ct)  # final forces
        ax_cm, f_hitch = _towed_x(v, g, body, ext, sfx, sc)
        ay_cm = sfy / v.mass + sc[S_GBY]
        rdot = (mz - (ext[E_HY] - v.yc) * f_hitch) / v.iz
        vxo, vyo = _integrate(v, g, body, wheel, st.acc, cpsi, spsi, ax_cm, ay_cm, rdot, f_hitch, ct, sc)
        if (step + 1) % log_every == 0 and log_row < st.log.shape[0]:
            _log(v, st, log_row, vxo, vyo, ax_cm, ay_cm, rdot, az_mean, ct, sc)
            log_row += 1
    return log_row
