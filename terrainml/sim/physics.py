"""Compiled physics kernel: planar rigid body + N wheels, wheel-terrain forces, PI wheel drives.

Integration: semi-implicit (symplectic) Euler at ``dt`` (default 1 ms). The tyre/soil contact is
stiff at low speed (dF/d(slip velocity) ~ k / v), so each contact force gets a linearly implicit
correction (Rosenbrock-Euler with a per-contact diagonal Jacobian: wheel inertia J/R^2 and the
wheel's share of the body mass; slope = max(local, secant to the predicted slip)): the fixed points (steady slip, steady turns) are those of the
explicit model, only the stiff transient is damped. The force law's slip uses
``max(|omega R|, |v_long|, 0.05 m/s)`` as denominator, and the lateral slip angle uses
``max(|v_long|, 0.25 m/s)`` in its denominator (low-speed tyre regularisation).

State layout (float64 arrays, mutated in place)
-----------------------------------------------
body  : [X, Y, psi, u, w, r, ax_cm, ay_cm, r_dot]  (CoM velocity u, w in body axes; ax/ay inertial
        CoM acceleration in body axes; previous-step values used for load transfer)
wheel : (7, N) rows omega, delta, integ (PI integrator, N m), omega_filt (drive's reported speed,
        first-order lag), dist (m travelled, roughness), tau (motor torque), load (N)
acc   : [energy_J, distance_m, time_s]

Uses numba when installed (``pip install numba``); otherwise runs the same code as plain Python
(slow, ~50x real time less). ``HAVE_NUMBA`` tells which.
"""

from __future__ import annotations

import math

import numpy as np

from terrainml._numba import HAVE_NUMBA, njit  # noqa: F401  (HAVE_NUMBA re-exported)

G = 9.81
B_X, B_Y, B_PSI, B_U, B_W, B_R, B_AX, B_AY, B_RDOT = range(9)
W_OMEGA, W_DELTA, W_INTEG, W_OFILT, W_DIST, W_TAU, W_LOAD = range(7)
N_WROWS = 7
# log columns (one row per logged substep)
LOG_COLS = ("t", "x", "y", "psi", "vx", "vy", "r", "ax", "ay", "rdot", "az")
L_T, L_X, L_Y, L_PSI, L_VX, L_VY, L_R, L_AX, L_AY, L_RDOT, L_AZ = range(11)
# per-wheel log blocks (each N wide), after the body columns
WLOG = ("omega", "omega_filt", "delta", "tau", "v_long", "v_lat", "load", "cell")
N_LOG_BODY = len(LOG_COLS)
V_REG = 0.05   # m/s: slip denominator floor for the force law (low-speed regularisation)


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
    if s_idx_f < 0.0:
        s_idx_f = 0.0
    if s_idx_f > n_slip - 1.0:
        s_idx_f = n_slip - 1.0
    i = int(s_idx_f)
    if i >= n_slip - 1:
        i = n_slip - 2
    fs = s_idx_f - i
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


@njit(cache=True)
def run_substeps(n_sub, dt, body, wheel, acc, omega_cmd, delta_cmd,
                 wx, wy, com, geom, ctrl, load_pinv, static_loads,
                 h_tab, r_tab, y_tab, hmax_tab, load_grid, alpha_lo, alpha_step,
                 rough_amp, rough_k, rough_phase,
                 lay_grid, lay_cell, lay_ox, lay_oy,
                 log, log_row, log_every):
    """Advance ``n_sub`` substeps; log every ``log_every``-th; return the next free log row.

    geom : [mass, Iz, R_wheel, J_wheel, com_h, w_ref]
    ctrl : [Kp, Ki, tau_max, steer_rate_max, steer_deadband, steer_tau, omega_lag_tau]
    com  : [xc, yc]
    """
    n = wx.shape[0]
    mass = geom[0]
    iz = geom[1]
    rw = geom[2]
    jw = geom[3]
    hcg = geom[4]
    w_ref = geom[5]
    kp = ctrl[0]
    ki = ctrl[1]
    tau_max = ctrl[2]
    srate = ctrl[3]
    sdb = ctrl[4]
    stau = ctrl[5]
    lag_tau = ctrl[6]
    xc = com[0]
    yc = com[1]
    n_load = h_tab.shape[1]
    n_slip = h_tab.shape[2]
    n_alpha = y_tab.shape[1]
    s_scale = (n_slip - 1) / 2.0
    nx = lay_grid.shape[0]
    ny = lay_grid.shape[1]
    m_i = mass / n
    fx = np.empty(n)
    fy = np.empty(n)
    hh = np.empty(n)
    kd = np.empty(n)
    fyl = np.empty(n)
    ky = np.empty(n)
    rr = np.empty(n)
    cs = np.empty(n)
    sn = np.empty(n)
    vlong = np.empty(n)
    vlat = np.empty(n)
    ddelta = np.empty(n)
    hmaxw = np.empty(n)
    azw = np.empty(n)
    cell = np.empty(n, dtype=np.int64)
    dens = np.empty(n)
    hraw = np.empty(n)
    sl = np.empty(n)
    lfs = np.empty(n)
    for step in range(n_sub):
        u = body[B_U]
        w = body[B_W]
        r = body[B_R]
        psi = body[B_PSI]
        cpsi = math.cos(psi)
        spsi = math.sin(psi)
        # ---- steering actuators (rate limit, dead band, first-order approach)
        for i in range(n):
            err = delta_cmd[i] - wheel[W_DELTA, i]
            if abs(err) <= sdb:
                ddelta[i] = 0.0
            else:
                d = err / stau
                if d > srate:
                    d = srate
                elif d < -srate:
                    d = -srate
                ddelta[i] = d
        # ---- wheel loads: static + load transfer (previous accelerations) + roughness
        ax = body[B_AX]
        ay = body[B_AY]
        b1 = mass * G
        b2 = mass * G * xc - mass * ax * hcg
        b3 = mass * G * yc - mass * ay * hcg
        az_mean = 0.0
        for i in range(n):
            ld = load_pinv[i, 0] * b1 + load_pinv[i, 1] * b2 + load_pinv[i, 2] * b3
            # contact-point world position -> layout cell
            px = body[B_X] + cpsi * wx[i] - spsi * wy[i]
            py = body[B_Y] + spsi * wx[i] + cpsi * wy[i]
            ix = int(math.floor((px - lay_ox) / lay_cell))
            iy = int(math.floor((py - lay_oy) / lay_cell))
            if ix < 0:
                ix = 0
            elif ix > nx - 1:
                ix = nx - 1
            if iy < 0:
                iy = 0
            elif iy > ny - 1:
                iy = ny - 1
            c = ix * ny + iy
            cell[i] = c
            vxi = u - r * (wy[i] - yc)
            vyi = w + r * (wx[i] - xc)
            speed2 = vxi * vxi + vyi * vyi
            zdd = 0.0
            for k in range(rough_k.shape[1]):
                zdd -= rough_amp[c, k] * rough_k[c, k] * rough_k[c, k] * math.sin(
                    rough_k[c, k] * wheel[W_DIST, i] + rough_phase[i, k])
            zdd *= speed2
            azw[i] = zdd
            az_mean += zdd / n
            f = 1.0 + zdd / G
            if f < 0.0:
                f = 0.0
            ld = ld * f
            if ld < 0.0:
                ld = 0.0
            wheel[W_LOAD, i] = ld
            # ---- kinematics at the wheel
            de = wheel[W_DELTA, i]
            cs[i] = math.cos(de)
            sn[i] = math.sin(de)
            vlong[i] = vxi * cs[i] + vyi * sn[i]
            vlat[i] = -vxi * sn[i] + vyi * cs[i]
            # ---- longitudinal force from the tables
            om = wheel[W_OMEGA, i]
            vw = om * rw
            den = max(abs(vw), abs(vlong[i]), V_REG)
            s = (vw - vlong[i]) / den
            dens[i] = den
            if s > 1.0:
                s = 1.0
            elif s < -1.0:
                s = -1.0
            lf = _load_index(ld / w_ref, load_grid)
            hv, hd = _interp_table(h_tab, c, lf, (s + 1.0) * s_scale, n_load, n_slip)
            rv, rd = _interp_table(r_tab, c, lf, (s + 1.0) * s_scale, n_load, n_slip)
            hh[i] = hv * w_ref
            hraw[i] = hh[i]
            sl[i] = s
            lfs[i] = lf
            kd[i] = hd * w_ref * s_scale / den          # dH / d(slip velocity)
            rr[i] = rv * w_ref * math.tanh(vlong[i] / 0.02)
            il = int(lf)
            if il >= n_load - 1:
                il = n_load - 2
            fl = lf - il
            hmaxw[i] = (hmax_tab[c, il] * (1.0 - fl) + hmax_tab[c, il + 1] * fl) * w_ref
            # ---- lateral force
            alpha = math.atan2(vlat[i], max(abs(vlong[i]), 0.25))
            af = (alpha - alpha_lo) / alpha_step
            if af < 0.0:
                af = 0.0
            if af > n_alpha - 1.0:
                af = n_alpha - 1.0
            ia = int(af)
            if ia >= n_alpha - 1:
                ia = n_alpha - 2
            fa = af - ia
            y0 = y_tab[c, ia]
            y1 = y_tab[c, ia + 1]
            fyl[i] = (y0 + (y1 - y0) * fa) * ld
            dalpha_dv = 1.0 / max(abs(vlong[i]), 0.25) / (1.0 + alpha * alpha)
            ky[i] = -(y1 - y0) / alpha_step * ld * dalpha_dv     # -dF_y/dv_lat >= 0
            # ---- PI drive (current limit = torque limit)
            e = omega_cmd[i] - om
            tau = kp * e + wheel[W_INTEG, i]
            if tau > tau_max:
                tau = tau_max
            elif tau < -tau_max:
                tau = -tau_max
            else:
                wheel[W_INTEG, i] += ki * e * dt
            if wheel[W_INTEG, i] > tau_max:
                wheel[W_INTEG, i] = tau_max
            elif wheel[W_INTEG, i] < -tau_max:
                wheel[W_INTEG, i] = -tau_max
            wheel[W_TAU, i] = tau
        # ---- friction ellipse (combined slip)
        for i in range(n):
            lat_max = abs(y_tab[cell[i], 0]) * wheel[W_LOAD, i]
            if hmaxw[i] > 1e-9 and lat_max > 1e-9:
                rho = (hh[i] / hmaxw[i]) ** 2 + (fyl[i] / lat_max) ** 2
                if rho > 1.0:
                    q = 1.0 / math.sqrt(rho)
                    hh[i] *= q
                    fyl[i] *= q
        # ---- explicit accelerations
        sfx = 0.0
        sfy = 0.0
        mz = 0.0
        for i in range(n):
            fl_ = hh[i] - rr[i]
            fx[i] = fl_ * cs[i] - fyl[i] * sn[i]
            fy[i] = fl_ * sn[i] + fyl[i] * cs[i]
            sfx += fx[i]
            sfy += fy[i]
            mz += (wx[i] - xc) * fy[i] - (wy[i] - yc) * fx[i]
        ud = sfx / mass + r * w
        wd = sfy / mass - r * u
        rdot = mz / iz
        # ---- linearly implicit contact corrections
        for i in range(n):
            dxi = wx[i] - xc
            dyi = wy[i] - yc
            aix = ud - rdot * dyi
            aiy = wd + rdot * dxi
            omd = (wheel[W_TAU, i] - rw * hh[i]) / jw
            dvl = aix * cs[i] + aiy * sn[i] + vlat[i] * ddelta[i]
            dvt = -aix * sn[i] + aiy * cs[i] - vlong[i] * ddelta[i]
            bl = rw * rw / jw + 1.0 / m_i
            # slope for the implicit step: the larger of the local slope and the secant to the
            # explicitly predicted slip (robust at the corners of free-slip dead zones)
            ddel = dt * (rw * omd - dvl)
            kdd = kd[i]
            if abs(ddel) > 1e-12:
                s_pred = sl[i] + ddel / dens[i]
                if s_pred > 1.0:
                    s_pred = 1.0
                elif s_pred < -1.0:
                    s_pred = -1.0
                hp, _ = _interp_table(h_tab, cell[i], lfs[i], (s_pred + 1.0) * s_scale, n_load, n_slip)
                ksec = (hp * w_ref - hraw[i]) / ddel
                if ksec > kdd:
                    kdd = ksec
            if kdd > 0.0:
                hh[i] += kdd * ddel / (1.0 + kdd * dt * bl)
            bt = 1.0 / m_i + (dxi * dxi + dyi * dyi) / iz
            kyy = ky[i]
            if kyy > 0.0:
                fyl[i] -= kyy * dt * dvt / (1.0 + kyy * dt * bt)
        # ---- final forces, semi-implicit Euler
        sfx = 0.0
        sfy = 0.0
        mz = 0.0
        for i in range(n):
            fl_ = hh[i] - rr[i]
            fx[i] = fl_ * cs[i] - fyl[i] * sn[i]
            fy[i] = fl_ * sn[i] + fyl[i] * cs[i]
            sfx += fx[i]
            sfy += fy[i]
            mz += (wx[i] - xc) * fy[i] - (wy[i] - yc) * fx[i]
        ax_cm = sfx / mass
        ay_cm = sfy / mass
        rdot = mz / iz
        body[B_U] = u + dt * (ax_cm + r * w)
        body[B_W] = w + dt * (ay_cm - r * u)
        body[B_R] = r + dt * rdot
        body[B_AX] = ax_cm
        body[B_AY] = ay_cm
        body[B_RDOT] = rdot
        u2 = body[B_U]
        w2 = body[B_W]
        r2 = body[B_R]
        # origin velocity (body axes): v_o = v_cm + omega x (O - CM)
        vxo = u2 + r2 * yc
        vyo = w2 - r2 * xc
        body[B_X] += dt * (cpsi * vxo - spsi * vyo)
        body[B_Y] += dt * (spsi * vxo + cpsi * vyo)
        body[B_PSI] = psi + dt * r2
        for i in range(n):
            om = wheel[W_OMEGA, i]
            om2 = om + dt * (wheel[W_TAU, i] - rw * hh[i]) / jw
            wheel[W_OMEGA, i] = om2
            wheel[W_DELTA, i] += dt * ddelta[i]
            wheel[W_OFILT, i] += dt / lag_tau * (om2 - wheel[W_OFILT, i])
            vxi = u2 - r2 * (wy[i] - yc)
            vyi = w2 + r2 * (wx[i] - xc)
            wheel[W_DIST, i] += dt * math.sqrt(vxi * vxi + vyi * vyi)
            acc[0] += dt * wheel[W_TAU, i] * om2
        acc[1] += dt * math.sqrt(vxo * vxo + vyo * vyo)
        acc[2] += dt
        # ---- log
        if (step + 1) % log_every == 0 and log_row < log.shape[0]:
            row = log_row
            log[row, L_T] = acc[2]
            log[row, L_X] = body[B_X]
            log[row, L_Y] = body[B_Y]
            log[row, L_PSI] = body[B_PSI]
            log[row, L_VX] = vxo
            log[row, L_VY] = vyo
            log[row, L_R] = r2
            # inertial acceleration of the origin (IMU), body axes
            log[row, L_AX] = ax_cm + rdot * yc + r2 * r2 * xc
            log[row, L_AY] = ay_cm - rdot * xc + r2 * r2 * yc
            log[row, L_RDOT] = rdot
            log[row, L_AZ] = az_mean
            base = N_LOG_BODY
            for i in range(n):
                vxi = u2 - r2 * (wy[i] - yc)
                vyi = w2 + r2 * (wx[i] - xc)
                de = wheel[W_DELTA, i]
                log[row, base + i] = wheel[W_OMEGA, i]
                log[row, base + n + i] = wheel[W_OFILT, i]
                log[row, base + 2 * n + i] = de
                log[row, base + 3 * n + i] = wheel[W_TAU, i]
                log[row, base + 4 * n + i] = vxi * math.cos(de) + vyi * math.sin(de)
                log[row, base + 5 * n + i] = -vxi * math.sin(de) + vyi * math.cos(de)
                log[row, base + 6 * n + i] = wheel[W_LOAD, i]
                log[row, base + 7 * n + i] = cell[i]
            log_row += 1
    return log_row
