"""The EKF's compiled (numba) kernels and its model (design §7).

Numba's on-disk cache only watches the file a kernel is defined in: a kernel calling a compiled
function (or reading a constant) from another file could be served stale after that file is
edited. The kernels here therefore call only kernels of this file, and constants that live
elsewhere (``DEAD_BAND_MPS``) are passed as arguments.

EKF (:class:`terrainml.estimation.ekf.Ekf` is a thin wrapper). The state layout (``I_*``), the
process model (:func:`process_model`, :func:`process_jacobian`) and the measurement model
(:func:`fill_linear_H`, :func:`fill_wheel_H`, :func:`h_row`) are defined here once; the filter
equations are :func:`predict_core` and :func:`update_core`. Entry points, called from Python with
the robot and tuning packed in an :class:`EkfModel` and ``x, P`` and the gate memory in an
:class:`EkfState`:

* :func:`predict_kernel`, :func:`update_kernel`: one EKF step each (``Ekf.predict``/``update``);
* :func:`step_kernel`: predict then update in one call (``Ekf.step``, the online tick);
* :func:`batch_kernel`: the same over every row of a table (``Ekf.batch_filter``: no Python
  between ticks).

All of them run the same two functions, so online, offline and batch results are identical. The
dense numpy form of the same filter, its specification, is :mod:`terrainml.estimation.reference`
(these kernels are tested against it to 1e-9).

The entry points take both packs as *plain tuples* (``tuple(model)``) and rebuild the named
tuple inside: numba types a plain tuple of arrays in C, a ``NamedTuple`` in Python (about 2 us
a call, a quarter of an online tick). The functions taking the packs are inlined
(``inline="always"``): a call would copy the packs by value.

Why the EKF loops look the way they do (speed without changing a single bit of the result):

* F is the identity plus 13 entries, and a row of H has at most 4 nonzeros (``vx, vy, r`` and
  the wheel's steering angle). The kernels visit only these structural nonzeros (index lists
  ``F_nz``/``H_nz`` built once by ``Ekf``), in ascending column order, so every sum adds the
  same terms in the same order as the dense product; the terms skipped are exact zeros.
* Products are written in "axpy" form, ``out[i, :] += a * B[k, :]``: the inner loop runs over a
  contiguous row with independent outputs, which LLVM vectorises without reassociating any sum
  (a dot-product loop ``acc += a[k] * b[k]`` is one long dependency chain: slow, and it cannot
  be vectorised without changing the rounding).

The online tick's measurement step (:func:`measurements_tick`) is here too; its per-wheel step
and the slip and dynamic-state rules are :mod:`._wheel_kernel` (importable from here).

``HAVE_NUMBA`` tells whether the compiled path is available; with ``TERRAINML_NO_NUMBA=1`` the
same functions run as plain Python (slow, same numbers).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from terrainml._numba import HAVE_NUMBA, njit  # noqa: F401  (HAVE_NUMBA re-exported)
from terrainml.estimation._wheel_kernel import (BRAKING, IDLE, MAX_P_DIAG, MAX_SPEED_MPS,  # noqa: F401
                                                SLIP_MEMORY_CLIP, SLIP_MEMORY_MIN_SPEED_MPS, STEADY, TRACTION,
                                                lag_step, manoeuvre_gain, manoeuvre_step, slip_ratio_scalar,
                                                state_machine_step, wheels_tick)

TWO_PI = 2.0 * math.pi
# state layout: x = [X, Y, psi, vx, vy, r, ax, ay, delta_1 .. delta_Ns, bg] (ekf.py docstring)
I_X, I_Y, I_PSI, I_VX, I_VY, I_R, I_AX, I_AY = range(8)
N_BASE = 8  # states before the steering angles; the gyro bias is the last state
# measurement row kinds (PlanarModel.rows); every row but the wheel rows is linear in x
K_WHEEL, K_IMU_AX, K_IMU_AY, K_IMU_RATE, K_YAW, K_STEER, K_CAM_VX, K_CAM_VY, K_CAM_RATE = range(9)
# gate_state: int64 array (3,) (see Ekf.update for the rules)
G_N_GATED, G_RUN, G_RELEASE = 0, 1, 2


class EkfModel(NamedTuple):
    """What the EKF kernels know of the robot and the tuning (built once by ``Ekf``)."""

    Q0: np.ndarray  # (n, n) process noise per nominal tick
    nominal_dt_s: float  # tick length Q0 refers to (s)
    H_const: np.ndarray  # (m, n) state-independent entries of H (wheel rows zero)
    F_nz: np.ndarray  # (n, k) int64, columns where row i of F can be nonzero (ascending, -1 pad)
    F_nnz: np.ndarray  # (n,) int64, how many
    H_nz: np.ndarray  # (m, k) int64, the same for H
    H_nnz: np.ndarray  # (m,) int64
    angle_rows: np.ndarray  # (m,) bool, innovation wrapped to (-pi, pi]
    gated_rows: np.ndarray  # (m,) bool, rows the chi-square gate may drop
    gate_max_ticks: int  # gate released after this many consecutive gated ticks
    n_wheel_rows: int  # the first rows of h are the wheel speeds
    wheel_xy_m: np.ndarray  # (N, 2) wheel contact centres, body frame (m)
    steer_state: np.ndarray  # (N,) int64, state index of each wheel's steering angle, -1: fixed
    wheel_radius_m: float


class EkfState(NamedTuple):
    """The filter's memory: arrays the kernels update in place."""

    x: np.ndarray  # (n,) state estimate
    P: np.ndarray  # (n, n) state covariance
    gate_state: np.ndarray  # (3,) int64: rows gated so far, consecutive gated ticks, released
    y: np.ndarray  # (m,) last innovations (NaN: row not used)
    S_diag: np.ndarray  # (m,) last innovation variances (NaN: row not used)


@njit(cache=True)
def wrap_scalar(a):
    """Angle wrapped to (-pi, pi] (rad): the compiled twin of :func:`terrainml.angles.wrap_angle`."""
    w = (a + math.pi) % TWO_PI - math.pi
    return math.pi if w == -math.pi else w


# --------------------------------------------------------------------- EKF: process model
@njit(cache=True)
def process_model(x, dt):
    """x = f(x) in place, tick length ``dt`` (s); signs of thesis eq. 4.33-4.34."""
    c = math.cos(x[I_PSI])
    s = math.sin(x[I_PSI])
    vx, vy, r = x[I_VX], x[I_VY], x[I_R]
    x[I_X] += dt * (vx * c - vy * s)  # X' = X + T (vx cos psi - vy sin psi)
    x[I_Y] += dt * (vx * s + vy * c)  # Y' = Y + T (vx sin psi + vy cos psi)
    x[I_PSI] = wrap_scalar(x[I_PSI] + dt * r)  # psi' = psi + T r
    x[I_VX] = vx + dt * (x[I_AX] + r * vy)  # vx' = vx + T (ax + r vy)
    x[I_VY] = vy + dt * (x[I_AY] - r * vx)  # vy' = vy + T (ay - r vx)
    # r, ax, ay, delta, bg: random walks (x' = x)


@njit(cache=True)
def process_jacobian(F, x, dt):
    """Write the state-dependent entries of F = df/dx at ``x`` into ``F`` (identity elsewhere)."""
    c = math.cos(x[I_PSI])
    s = math.sin(x[I_PSI])
    vx, vy, r = x[I_VX], x[I_VY], x[I_R]
    F[I_X, I_PSI] = -dt * (vx * s + vy * c)  # dX'/dpsi
    F[I_X, I_VX] = dt * c
    F[I_X, I_VY] = -dt * s
    F[I_Y, I_PSI] = dt * (vx * c - vy * s)  # dY'/dpsi
    F[I_Y, I_VX] = dt * s
    F[I_Y, I_VY] = dt * c
    F[I_PSI, I_R] = dt
    F[I_VX, I_VY] = dt * r
    F[I_VX, I_R] = dt * vy
    F[I_VX, I_AX] = dt
    F[I_VY, I_VX] = -dt * r
    F[I_VY, I_R] = -dt * vx
    F[I_VY, I_AY] = dt


# --------------------------------------------------------------------- EKF: measurement model
@njit(cache=True)
def fill_linear_H(H, kind, state_of_row, cam_xy_m, i_bias):
    """Write the rows of H that do not depend on x (every row but the wheel rows; h_i = H_i x).

    ``kind`` (m,) row kinds ``K_*``; ``state_of_row`` (m,) steering state of a steer row.
    """
    for k in range(H.shape[0]):
        kd = kind[k]
        if kd == K_IMU_AX:  # ax_imu = ax
            H[k, I_AX] = 1.0
        elif kd == K_IMU_AY:  # ay_imu = ay
            H[k, I_AY] = 1.0
        elif kd == K_IMU_RATE:  # r_imu = r + bg
            H[k, I_R] = 1.0
            H[k, i_bias] = 1.0
        elif kd == K_YAW:  # psi_imu = psi_cam = psi
            H[k, I_PSI] = 1.0
        elif kd == K_STEER:  # d_j = delta_j
            H[k, state_of_row[k]] = 1.0
        elif kd == K_CAM_VX:  # vx_cam = vx - r y_c  (lever arm, eq. 6.6)
            H[k, I_VX] = 1.0
            H[k, I_R] = -cam_xy_m[1]
        elif kd == K_CAM_VY:  # vy_cam = vy + r x_c
            H[k, I_VY] = 1.0
            H[k, I_R] = cam_xy_m[0]
        elif kd == K_CAM_RATE:  # r_cam = r
            H[k, I_R] = 1.0


@njit(cache=True)
def fill_wheel_H(H, x, wheel_xy_m, steer_state, wheel_radius_m):
    """Write the wheel rows of H (the first N rows): analytic derivatives of eq. 4.46.

    w_i = (u c + w s) / R with u = vx - r y_i, w = vy + r x_i, c = cos d_i, s = sin d_i:
    dw/dvx = c / R, dw/dvy = s / R, dw/dr = (x_i s - y_i c) / R, dw/dd_i = (w c - u s) / R.
    """
    inv_r = 1.0 / wheel_radius_m
    for i in range(steer_state.shape[0]):
        si = steer_state[i]
        d = x[si] if si >= 0 else 0.0
        c = math.cos(d)
        s = math.sin(d)
        H[i, I_VX] = c * inv_r
        H[i, I_VY] = s * inv_r
        H[i, I_R] = (wheel_xy_m[i, 0] * s - wheel_xy_m[i, 1] * c) * inv_r
        if si >= 0:
            u = x[I_VX] - x[I_R] * wheel_xy_m[i, 1]
            w = x[I_VY] + x[I_R] * wheel_xy_m[i, 0]
            H[i, si] = (w * c - u * s) * inv_r


@njit(cache=True)
def h_row(H, x, i, n_wheel_rows, H_nz, H_nnz):
    """h_i(x) from the rows of H: a wheel row is v_long_i / R = H_i[vx, vy, r] . (vx, vy, r)
    (exactly linear in the velocities), every other row h_i = H_i x (over its nonzeros)."""
    if i < n_wheel_rows:
        return H[i, I_VX] * x[I_VX] + H[i, I_VY] * x[I_VY] + H[i, I_R] * x[I_R]
    h = 0.0
    for b in range(H_nnz[i]):
        j = H_nz[i, b]
        h += H[i, j] * x[j]
    return h


# --------------------------------------------------------------------- EKF: the filter
@njit(cache=True, inline="always")
def predict_core(m, st, dt, q_scale):
    """x = f(x);  P = F P F^T + Q0 q_scale  (F at the prior mean, before x moves)."""
    x, P = st.x, st.P
    n = x.shape[0]
    F = np.eye(n)
    process_jacobian(F, x, dt)
    process_model(x, dt)
    # tmp = F P  (row i of tmp: sum over the nonzeros k of F's row i of F[i, k] P[k, :])
    tmp = np.zeros((n, n))
    for i in range(n):
        for a in range(m.F_nnz[i]):
            k = m.F_nz[i, a]
            f = F[i, k]
            for j in range(n):
                tmp[i, j] += f * P[k, j]
    # P = tmp F^T + Q0 q_scale  ((tmp F^T)[i, j] = sum over the nonzeros k of F's row j)
    for i in range(n):
        for j in range(n):
            acc = 0.0
            for a in range(m.F_nnz[j]):
                k = m.F_nz[j, a]
                acc += tmp[i, k] * F[j, k]
            P[i, j] = acc + m.Q0[i, j] * q_scale


@njit(cache=True, inline="always")
def _rows_used(m, x, use, z, H):
    """Indices of the rows used (ascending) and the innovations y = z - h(x) of all of them
    (angles wrapped); refreshes the wheel rows of ``H`` when one of them is used."""
    mz = z.shape[0]
    any_wheel = False
    for i in range(m.n_wheel_rows):
        if use[i]:
            any_wheel = True
    if any_wheel:
        fill_wheel_H(H, x, m.wheel_xy_m, m.steer_state, m.wheel_radius_m)
    idx = np.empty(mz, dtype=np.int64)
    yv = np.empty(mz)
    k = 0
    for i in range(mz):
        if use[i]:
            idx[k] = i
            k += 1
            yy = z[i] - h_row(H, x, i, m.n_wheel_rows, m.H_nz, m.H_nnz)
            if m.angle_rows[i]:
                yy = wrap_scalar(yy)  # wrapped angle innovation
            yv[i] = yy
    return idx, k, yv


@njit(cache=True, inline="always")
def _gate(m, P, H, idx, k, yv, r_diag, gate, release):
    """Per-row chi-square gate: drop a gated row if y_i^2 > gate S_ii, S_ii = H_i P H_i^T + R_i
    (kept when the gate is released: the prediction is wrong, not the sensor). Compacts ``idx``;
    returns (rows kept, rows dropped, any row disagreed)."""
    n_bad = 0
    agree = True
    keep = 0
    for a in range(k):
        i = idx[a]
        bad = False
        if m.gated_rows[i]:
            sii = r_diag[i]
            for b in range(m.H_nnz[i]):
                p = m.H_nz[i, b]
                hp = 0.0
                for c2 in range(m.H_nnz[i]):
                    q = m.H_nz[i, c2]
                    hp += H[i, q] * P[q, p]
                sii += hp * H[i, p]
            bad = yv[i] * yv[i] > gate * sii
        if bad:
            agree = False
            if not release:
                n_bad += 1
                continue
        idx[keep] = i
        keep += 1
    return keep, n_bad, agree


@njit(cache=True)
def _gate_bookkeeping(gate_state, gate, n_bad, agree, gate_max_ticks):
    """Gate release rule (Ekf.update): released after ``gate_max_ticks`` consecutive gated ticks,
    re-armed as soon as prediction and sensors agree again."""
    gate_state[G_N_GATED] += n_bad
    if gate > 0.0 and agree:
        gate_state[G_RELEASE] = 0
    gate_state[G_RUN] = gate_state[G_RUN] + 1 if n_bad > 0 else 0
    if gate_state[G_RUN] > gate_max_ticks:
        gate_state[G_RELEASE] = 1
        gate_state[G_RUN] = 0


@njit(cache=True)
def _cholesky_solve(S, X):
    """X = S^-1 X in place for S symmetric positive definite (lower triangle read), all columns
    at once. Returns False, X untouched, if S is not positive definite."""
    k = S.shape[0]
    L = np.zeros((k, k))
    for a in range(k):  # S = L L^T
        for b in range(a + 1):
            acc = S[a, b]
            for c2 in range(b):
                acc -= L[a, c2] * L[b, c2]
            if a == b:
                if acc <= 0.0:
                    return False
                L[a, a] = math.sqrt(acc)
            else:
                L[a, b] = acc / L[b, b]
    ncol = X.shape[1]
    for a in range(k):  # forward: L W = X
        for c2 in range(a):
            la = L[a, c2]
            for col in range(ncol):
                X[a, col] -= la * X[c2, col]
        inv = L[a, a]
        for col in range(ncol):
            X[a, col] = X[a, col] / inv
    for a in range(k - 1, -1, -1):  # backward: L^T V = W
        for c2 in range(a + 1, k):
            la = L[c2, a]
            for col in range(ncol):
                X[a, col] -= la * X[c2, col]
        inv = L[a, a]
        for col in range(ncol):
            X[a, col] = X[a, col] / inv
    return True


@njit(cache=True, inline="always")
def _joseph_covariance(m, P, H, X, idx, k, r_diag):
    """P = (I - K H) P (I - K H)^T + K R K^T in place, K^T = ``X[:, :n]`` (k used rows)."""
    n = P.shape[0]
    # A = I - K H; At holds A transposed (At[q, p] = A[p, q])
    At = np.zeros((n, n))
    for a in range(k):  # At[q, :] accumulates sum_a H[a, q] K[:, a]
        i = idx[a]
        for b in range(m.H_nnz[i]):
            q = m.H_nz[i, b]
            hq = H[i, q]
            for p in range(n):
                At[q, p] += X[a, p] * hq
    for q in range(n):
        for p in range(n):
            At[q, p] = (1.0 if p == q else 0.0) - At[q, p]
    T = np.zeros((n, n))  # T = A P
    for p in range(n):
        for c2 in range(n):
            apc = At[c2, p]
            if apc != 0.0:  # A has unit columns where no used row looks (X, Y, ...)
                for q in range(n):
                    T[p, q] += apc * P[c2, q]
    M = np.zeros((n, n))  # T A^T
    KRK = np.zeros((n, n))  # K R K^T
    for p in range(n):  # full rows (contiguous, vectorised); only the upper triangle is kept
        for c2 in range(n):
            tpc = T[p, c2]
            for q in range(n):
                M[p, q] += tpc * At[c2, q]
        for a in range(k):
            w = X[a, p] * r_diag[idx[a]]
            for q in range(n):
                KRK[p, q] += w * X[a, q]
    for p in range(n):  # upper triangle, mirrored: P exactly symmetric
        for q in range(p, n):
            P[p, q] = M[p, q] + KRK[p, q]
    for p in range(n):
        for q in range(p):
            P[p, q] = P[q, p]


@njit(cache=True, inline="always")
def update_core(m, st, z, use, r_diag, gate):
    """Joseph-form update (see Ekf.update) with the rows ``use``; returns ``(nis, dof)``.

    y = z - h(x);  S = H P H^T + R;  K = P H^T S^-1;  x = x + K y
    P = (I - K H) P (I - K H)^T + K R K^T;  NIS = y^T S^-1 y
    ``gate`` <= 0 disables the gate.
    """
    x, P = st.x, st.P
    n = x.shape[0]
    for i in range(z.shape[0]):  # (element loops: a slice assignment costs seconds of compile time)
        st.y[i] = np.nan
        st.S_diag[i] = np.nan
    H = m.H_const.copy()
    idx, k, yv = _rows_used(m, x, use, z, H)
    n_bad, agree = 0, True
    if gate > 0.0:
        k, n_bad, agree = _gate(m, P, H, idx, k, yv, r_diag, gate, st.gate_state[G_RELEASE] != 0)
    _gate_bookkeeping(st.gate_state, gate, n_bad, agree, m.gate_max_ticks)
    if k == 0:
        return np.nan, 0
    # ---- HP = H P (k, n)
    HP = np.zeros((k, n))
    for a in range(k):
        i = idx[a]
        for b in range(m.H_nnz[i]):
            q = m.H_nz[i, b]
            hq = H[i, q]
            for p in range(n):
                HP[a, p] += hq * P[q, p]
    # ---- S = H P H^T + R (k, k); lower triangle computed, mirrored
    S = np.empty((k, k))
    for a in range(k):
        for b in range(a + 1):
            ib = idx[b]
            acc = 0.0
            for c2 in range(m.H_nnz[ib]):
                p = m.H_nz[ib, c2]
                acc += HP[a, p] * H[ib, p]
            S[a, b] = acc
            S[b, a] = acc
        S[a, a] += r_diag[idx[a]]
    # ---- solve S X = [HP | y]  ->  X[:, :n] = K^T, X[:, n] = S^-1 y
    X = np.empty((k, n + 1))
    for a in range(k):
        for p in range(n):
            X[a, p] = HP[a, p]
        X[a, n] = yv[idx[a]]
    if not _cholesky_solve(S, X):  # not positive definite (should not happen): least squares
        sol = np.linalg.lstsq(S, X.copy(), rcond=-1.0)[0]
        for a in range(k):
            for p in range(n + 1):
                X[a, p] = sol[a, p]
    # ---- x = x + K y
    for p in range(n):
        acc = 0.0
        for a in range(k):
            acc += X[a, p] * yv[idx[a]]
        x[p] += acc
    x[I_PSI] = wrap_scalar(x[I_PSI])
    _joseph_covariance(m, P, H, X, idx, k, r_diag)
    nis = 0.0  # NIS = y^T S^-1 y
    for a in range(k):
        nis += yv[idx[a]] * X[a, n]
        st.y[idx[a]] = yv[idx[a]]
        st.S_diag[idx[a]] = S[a, a]
    return nis, k


# --------------------------------------------------------------------- EKF: entry points
@njit(cache=True)
def predict_kernel(model, state, dt):
    """:func:`predict_core` over ``dt`` (Q0 is per ``nominal_dt_s`` tick). ``model``, ``state``:
    the fields of :class:`EkfModel` / :class:`EkfState` as plain tuples."""
    m = EkfModel(*model)
    predict_core(m, EkfState(*state), dt, dt / m.nominal_dt_s)


@njit(cache=True)
def update_kernel(model, state, z, use, r_diag, gate):
    """:func:`update_core`; returns (nis, dof)."""
    return update_core(EkfModel(*model), EkfState(*state), z, use, r_diag, gate)


@njit(cache=True)
def step_kernel(model, state, dt, z, use, r_diag, gate):
    """One tick: predict over ``dt`` (skipped when ``dt <= 0``), then update. Returns (nis, dof)."""
    m, st = EkfModel(*model), EkfState(*state)
    if dt > 0.0:
        predict_core(m, st, dt, dt / m.nominal_dt_s)
    return update_core(m, st, z, use, r_diag, gate)


@njit(cache=True)
def batch_kernel(model, state, t_s, Z, U, r_diag, gate, xs_out, nis_out, dof_out):
    """:func:`step_kernel` over every row of a table (``dt = t_s[k] - t_s[k - 1]``; row 0 is an
    update only); writes the state, NIS and rows used after each tick."""
    m, st = EkfModel(*model), EkfState(*state)
    for k in range(t_s.shape[0]):
        dt = t_s[k] - t_s[k - 1] if k > 0 else 0.0
        if dt > 0.0:
            predict_core(m, st, dt, dt / m.nominal_dt_s)
        nis, dof = update_core(m, st, Z[k], U[k], r_diag, gate)
        for j in range(st.x.shape[0]):
            xs_out[k, j] = st.x[j]
        nis_out[k] = nis
        dof_out[k] = dof


# --------------------------------------------------------------------- the online tick (online.py)
@njit(cache=True)
def measurements_tick(t_s, z_raw, row_valid, group_of_row, last_seen, angle, yaw_offset, any_alpha,
                      one_minus_alpha, z_f, prev_valid, z_out, use_out):
    """Rows used and measurements after yaw zeroing and the EMA pre-filters (eq. 6.12).

    Numba kernel: takes flat arrays and scalars, because numba compiles a call with plain arrays
    and numbers without boxing, and the online tick calls it every base period.

    ``last_seen[g]`` takes ``t_s`` when a row of group ``g`` is usable. Yaw rows are zeroed at
    their first valid sample. Pre-filter per used row: ``z_f = z_f + (1 - alpha) (z - z_f)``
    (angles: wrapped difference), restarted with the raw value after a gap; then ``z_out = z_f``.
    """
    m = z_raw.shape[0]
    for k in range(m):
        z_out[k] = z_raw[k]
        use_out[k] = row_valid[k]
        if row_valid[k]:
            last_seen[group_of_row[k]] = t_s
        if angle[k] and row_valid[k]:  # yaw zeroed at the first valid sample
            if math.isnan(yaw_offset[k]):
                yaw_offset[k] = z_raw[k]
            z_out[k] = wrap_scalar(z_raw[k] - yaw_offset[k])
    if any_alpha:
        for k in range(m):
            if use_out[k]:
                if not prev_valid[k]:  # first sample after a gap: restart the EMA
                    z_f[k] = z_out[k]
                else:
                    d = z_out[k] - z_f[k]
                    if angle[k]:
                        d = wrap_scalar(d)
                    z_f[k] = z_f[k] + one_minus_alpha[k] * d  # z = alpha z_prev + (1 - alpha) z_raw
            prev_valid[k] = use_out[k]
            z_out[k] = z_f[k]
