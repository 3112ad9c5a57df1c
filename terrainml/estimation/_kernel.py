"""Every compiled (numba) kernel of the estimator, in one file.

One file because numba's on-disk cache only watches the file a kernel is defined in: a kernel
calling a compiled function (or reading a constant) from another file could be served stale
after that file is edited. Constants that live elsewhere (``NOMINAL_DT_S``, ``DEAD_BAND_MPS``)
are therefore passed as arguments.

EKF (:class:`terrainml.estimation.ekf.Ekf`): the same equations as its numpy methods (the
readable reference, and the path taken when numba is not installed), written as explicit loops.
A test checks both paths agree to 1e-9 over a whole run. Entry points:

* :func:`predict_kernel`, :func:`update_kernel`: one EKF step each (``Ekf.predict``/``update``);
* :func:`step_kernel`: predict then update in one call (``Ekf.step``, the online tick: one
  dispatch, not two);
* :func:`batch_kernel`: the same over every row of a table (``Ekf.batch_filter``, the offline
  bare filter: no Python between ticks).

All of them run the same two functions, so online, offline and batch results are identical.

Why the EKF loops look the way they do (speed without changing a single bit of the result):

* F is the identity plus 13 entries, and a row of H has at most 4 nonzeros (``vx, vy, r`` and
  the wheel's steering angle). The kernels visit only these structural nonzeros (index lists
  ``F_nz``/``H_nz`` built once by ``Ekf``), in ascending column order, so every sum adds the
  same terms in the same order as the dense product; the terms skipped are exact zeros.
* Products are written in "axpy" form, ``out[i, :] += a * B[k, :]``: the inner loop runs over a
  contiguous row with independent outputs, which LLVM vectorises without reassociating any sum
  (a dot-product loop ``acc += a[k] * b[k]`` is one long dependency chain: slow, and it cannot
  be vectorised without changing the rounding).

Per-wheel slip and dynamic state (:mod:`.slip`, :mod:`.dynamic_state`): the per-tick rules as
scalar loops (:func:`slip_ratio_scalar`, :func:`lag_step`, :func:`manoeuvre_step`,
:func:`state_machine_step`), called by the classes of those modules and by the online tick
(:func:`measurements_tick`, :func:`wheels_tick`), so each rule has one implementation.

``HAVE_NUMBA`` tells whether the compiled path is available; set the environment variable
``TERRAINML_NO_NUMBA=1`` to force the numpy path (the kernels then run as plain Python, and
``Ekf`` uses its numpy methods).
"""
from __future__ import annotations

import math

import numpy as np

from terrainml._numba import HAVE_NUMBA, njit  # noqa: F401  (HAVE_NUMBA re-exported)

TWO_PI = 2.0 * math.pi
# gate_state: int64 array (3,) shared with Ekf (see Ekf.update for the rules)
G_N_GATED, G_RUN, G_RELEASE = 0, 1, 2
# dynamic-state codes, in the order of schema.WHEEL_STATES (re-exported by dynamic_state)
IDLE, STEADY, TRACTION, BRAKING = range(4)
# online health and slip memory (re-exported by online)
MAX_SPEED_MPS = 50.0  # beyond this the filter is declared diverged
MAX_P_DIAG = 1e6
SLIP_MEMORY_MIN_SPEED_MPS = 0.2  # slip is remembered only where the wheel moves this fast
SLIP_MEMORY_CLIP = 0.95


@njit(cache=True)
def _wrap(a):
    w = (a + math.pi) % TWO_PI - math.pi
    return math.pi if w == -math.pi else w


@njit(cache=True)
def predict_kernel(x, P, Q0, dt, q_scale, F, F_nz, F_nnz, tmp):
    """x = f(x);  P = F P F^T + Q0 q_scale.

    ``F`` (n, n) work array holding the identity off the state-dependent entries; row ``i`` of
    F has its nonzeros in columns ``F_nz[i, :F_nnz[i]]`` (ascending); ``tmp`` (n, n) work array.
    """
    n = x.shape[0]
    c = math.cos(x[2])
    s = math.sin(x[2])
    vx, vy, r = x[3], x[4], x[5]
    # Jacobian at the prior mean, before x moves (see ekf.fill_F)
    F[0, 2] = -dt * (vx * s + vy * c)
    F[0, 3] = dt * c
    F[0, 4] = -dt * s
    F[1, 2] = dt * (vx * c - vy * s)
    F[1, 3] = dt * s
    F[1, 4] = dt * c
    F[2, 5] = dt
    F[3, 4] = dt * r
    F[3, 5] = dt * vy
    F[3, 6] = dt
    F[4, 3] = -dt * r
    F[4, 5] = -dt * vx
    F[4, 7] = dt
    x[0] += dt * (vx * c - vy * s)  # X' = X + T (vx cos psi - vy sin psi)
    x[1] += dt * (vx * s + vy * c)  # Y' = Y + T (vx sin psi + vy cos psi)
    x[2] = _wrap(x[2] + dt * r)  # psi' = psi + T r
    x[3] = vx + dt * (x[6] + r * vy)  # vx' = vx + T (ax + r vy)
    x[4] = vy + dt * (x[7] - r * vx)  # vy' = vy + T (ay - r vx)
    # tmp = F P  (row i of tmp: sum over the nonzeros k of F's row i of F[i, k] P[k, :])
    for i in range(n):
        for j in range(n):
            tmp[i, j] = 0.0
        for a in range(F_nnz[i]):
            k = F_nz[i, a]
            f = F[i, k]
            for j in range(n):
                tmp[i, j] += f * P[k, j]
    # P = tmp F^T + Q0 q_scale  ((tmp F^T)[i, j] = sum over the nonzeros k of F's row j)
    for i in range(n):
        for j in range(n):
            acc = 0.0
            for a in range(F_nnz[j]):
                k = F_nz[j, a]
                acc += tmp[i, k] * F[j, k]
            P[i, j] = acc + Q0[i, j] * q_scale


@njit(cache=True)
def update_kernel(x, P, H_all, H_nz, H_nnz, z, use, r_diag, angle, gated_rows, gate, gate_max_ticks,
                  gate_state, n_wheel_rows, wheel_xy, steer_state, radius, y_out, s_out):
    """Joseph-form update (see Ekf.update). Returns ``(nis, dof)``; ``dof = -1``: S was not
    positive definite, nothing was changed (x, P, gate_state) and the caller falls back.

    ``H_all`` (m, n) holds every row of H (wheel rows refreshed here); row ``i`` has its
    nonzeros in columns ``H_nz[i, :H_nnz[i]]`` (ascending). ``gate`` <= 0 disables the gate;
    ``gate_state`` int64 (3,): [rows gated so far, consecutive gated ticks, gate released].
    ``y_out``/``s_out`` (m,) receive innovations / S diagonals (NaN for rows not used).
    """
    n = x.shape[0]
    m = z.shape[0]
    for i in range(m):
        y_out[i] = np.nan
        s_out[i] = np.nan
    # ---- wheel rows of H (analytic, see ekf.fill_wheel_H), only if any is used
    any_wheel = False
    for i in range(n_wheel_rows):
        if use[i]:
            any_wheel = True
    inv_r = 1.0 / radius
    if any_wheel:
        for i in range(n_wheel_rows):
            si = steer_state[i]
            d = x[si] if si >= 0 else 0.0
            c = math.cos(d)
            s = math.sin(d)
            H_all[i, 3] = c * inv_r
            H_all[i, 4] = s * inv_r
            H_all[i, 5] = (wheel_xy[i, 0] * s - wheel_xy[i, 1] * c) * inv_r
            if si >= 0:
                u = x[3] - x[5] * wheel_xy[i, 1]
                w = x[4] + x[5] * wheel_xy[i, 0]
                H_all[i, si] = (w * c - u * s) * inv_r
    # ---- rows used, innovations y = z - h(x) (h is linear in x row by row: h_i = H_i x)
    idx = np.empty(m, dtype=np.int64)
    k = 0
    for i in range(m):
        if use[i]:
            idx[k] = i
            k += 1
    yv = np.empty(m)
    for a in range(k):
        i = idx[a]
        if i < n_wheel_rows:  # wheel row: v_long / R (exactly linear in vx, vy, r)
            h = H_all[i, 3] * x[3] + H_all[i, 4] * x[4] + H_all[i, 5] * x[5]
        else:
            h = 0.0
            for b in range(H_nnz[i]):
                j = H_nz[i, b]
                h += H_all[i, j] * x[j]
        yy = z[i] - h
        if angle[i]:
            yy = (yy + math.pi) % TWO_PI - math.pi  # wrapped angle innovation
        yv[i] = yy
    # ---- per-row chi-square gate: drop a gated row if y_i^2 > gate S_ii, S_ii = H_i P H_i^T + R_i
    release = gate_state[G_RELEASE] != 0
    n_bad = 0
    gated_now = False
    agree = True
    if gate > 0.0:
        keep = 0
        for a in range(k):
            i = idx[a]
            bad = False
            if gated_rows[i]:
                sii = r_diag[i]
                for b in range(H_nnz[i]):
                    p = H_nz[i, b]
                    hp = 0.0
                    for c2 in range(H_nnz[i]):
                        q = H_nz[i, c2]
                        hp += H_all[i, q] * P[q, p]
                    sii += hp * H_all[i, p]
                if yv[i] * yv[i] > gate * sii:
                    bad = True
            if bad:
                agree = False
                if not release:  # released: the prediction is wrong, not the sensor; keep it
                    n_bad += 1
                    continue
            idx[keep] = i
            keep += 1
        if n_bad > 0:
            gated_now = True
        k = keep
    if k == 0:
        _gate_bookkeeping(gate_state, gate, n_bad, gated_now, agree, gate_max_ticks)
        return np.nan, 0
    # ---- HP = H P (k, n)
    HP = np.zeros((k, n))
    for a in range(k):
        i = idx[a]
        for b in range(H_nnz[i]):
            q = H_nz[i, b]
            hq = H_all[i, q]
            for p in range(n):
                HP[a, p] += hq * P[q, p]
    # ---- S = H P H^T + R (k, k); lower triangle only (all the Cholesky factorisation reads)
    S = np.empty((k, k))
    for a in range(k):
        for b in range(a + 1):
            ib = idx[b]
            acc = 0.0
            for c2 in range(H_nnz[ib]):
                p = H_nz[ib, c2]
                acc += HP[a, p] * H_all[ib, p]
            S[a, b] = acc
        S[a, a] += r_diag[idx[a]]
    # ---- Cholesky S = L L^T
    L = np.zeros((k, k))
    for a in range(k):
        for b in range(a + 1):
            acc = S[a, b]
            for c2 in range(b):
                acc -= L[a, c2] * L[b, c2]
            if a == b:
                if acc <= 0.0:
                    return np.nan, -1  # not PD: caller falls back (nothing changed)
                L[a, a] = math.sqrt(acc)
            else:
                L[a, b] = acc / L[b, b]
    _gate_bookkeeping(gate_state, gate, n_bad, gated_now, agree, gate_max_ticks)
    # ---- solve S X = [HP | y]  ->  X[:, :n] = K^T, X[:, n] = S^-1 y  (all columns at once)
    X = np.empty((k, n + 1))
    for a in range(k):
        for p in range(n):
            X[a, p] = HP[a, p]
        X[a, n] = yv[idx[a]]
    for a in range(k):  # forward: L W = B
        for c2 in range(a):
            la = L[a, c2]
            for col in range(n + 1):
                X[a, col] -= la * X[c2, col]
        inv = L[a, a]
        for col in range(n + 1):
            X[a, col] = X[a, col] / inv
    for a in range(k - 1, -1, -1):  # backward: L^T V = W
        for c2 in range(a + 1, k):
            la = L[c2, a]
            for col in range(n + 1):
                X[a, col] -= la * X[c2, col]
        inv = L[a, a]
        for col in range(n + 1):
            X[a, col] = X[a, col] / inv
    # ---- x = x + K y
    for p in range(n):
        acc = 0.0
        for a in range(k):
            acc += X[a, p] * yv[idx[a]]
        x[p] += acc
    x[2] = _wrap(x[2])
    # ---- Joseph form: A = I - K H;  P = A P A^T + K R K^T.  At holds A transposed (At[q, p] = A[p, q])
    At = np.zeros((n, n))
    for a in range(k):  # At[q, :] accumulates sum_a H[a, q] K[:, a]
        i = idx[a]
        for b in range(H_nnz[i]):
            q = H_nz[i, b]
            hq = H_all[i, q]
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
    nis = 0.0  # NIS = y^T S^-1 y
    for a in range(k):
        nis += yv[idx[a]] * X[a, n]
        y_out[idx[a]] = yv[idx[a]]
        s_out[idx[a]] = S[a, a]
    return nis, k


@njit(cache=True)
def _gate_bookkeeping(gate_state, gate, n_bad, gated_now, agree, gate_max_ticks):
    """Gate release rule (Ekf.update): released after ``gate_max_ticks`` consecutive gated ticks,
    re-armed as soon as prediction and sensors agree again."""
    gate_state[G_N_GATED] += n_bad
    if gate > 0.0 and agree:
        gate_state[G_RELEASE] = 0
    gate_state[G_RUN] = gate_state[G_RUN] + 1 if gated_now else 0
    if gate_state[G_RUN] > gate_max_ticks:
        gate_state[G_RELEASE] = 1
        gate_state[G_RUN] = 0


@njit(cache=True)
def step_kernel(x, P, Q0, dt, nominal_dt, F, F_nz, F_nnz, tmp, H_all, H_nz, H_nnz, z, use, r_diag, angle,
                gated_rows, gate, gate_max_ticks, gate_state, n_wheel_rows, wheel_xy, steer_state, radius, y_out,
                s_out):
    """One tick: predict over ``dt`` (skipped when ``dt <= 0``; Q0 is per ``nominal_dt`` tick),
    then update. Returns (nis, dof)."""
    if dt > 0.0:
        predict_kernel(x, P, Q0, dt, dt / nominal_dt, F, F_nz, F_nnz, tmp)
    return update_kernel(x, P, H_all, H_nz, H_nnz, z, use, r_diag, angle, gated_rows, gate, gate_max_ticks,
                         gate_state, n_wheel_rows, wheel_xy, steer_state, radius, y_out, s_out)


@njit(cache=True)
def batch_kernel(start, t_s, Z, U, r_diag, x, P, Q0, nominal_dt, F, F_nz, F_nnz, tmp, H_all, H_nz, H_nnz, angle,
                 gated_rows, gate, gate_max_ticks, gate_state, n_wheel_rows, wheel_xy, steer_state, radius,
                 y_out, s_out, xs_out, nis_out, dof_out):
    """:func:`step_kernel` over rows ``start..`` of a table (``dt = t_s[k] - t_s[k - 1]``; row 0
    is an update only). Returns the row where an update could not run (S not positive definite,
    predict already applied) for the caller to finish in numpy, or ``len(t_s)`` when done."""
    for k in range(start, t_s.shape[0]):
        dt = t_s[k] - t_s[k - 1] if k > 0 else 0.0
        if dt > 0.0:
            predict_kernel(x, P, Q0, dt, dt / nominal_dt, F, F_nz, F_nnz, tmp)
        nis, dof = update_kernel(x, P, H_all, H_nz, H_nnz, Z[k], U[k], r_diag, angle, gated_rows, gate,
                                 gate_max_ticks, gate_state, n_wheel_rows, wheel_xy, steer_state, radius,
                                 y_out, s_out)
        if dof < 0:
            return k
        for j in range(x.shape[0]):
            xs_out[k, j] = x[j]
        nis_out[k] = nis
        dof_out[k] = dof
    return t_s.shape[0]


# --------------------------------------------------------------------- slip (slip.py)
@njit(cache=True)
def slip_ratio_scalar(v_ang_mps, v_long_mps, dead_band_mps):
    """:func:`slip_ratio` for one wheel and plain floats (same maths; the per-tick path, shared
    by :func:`slip_ratio_tick` and the online estimator's compiled tick)."""
    if v_ang_mps != v_ang_mps or v_long_mps != v_long_mps:  # NaN in -> NaN out
        return math.nan
    if abs(v_ang_mps) < dead_band_mps and abs(v_long_mps) < dead_band_mps:
        return 0.0  # dead band
    s = (v_ang_mps - v_long_mps) / max(abs(v_ang_mps), abs(v_long_mps))  # SAE split definition, eq. 7.7
    return 1.0 if s > 1.0 else (-1.0 if s < -1.0 else s)


@njit(cache=True)
def lag_step(y, u, g):
    """One tick of the first-order lag, in place: ``y += g (u - y)``, ``g = 1 - exp(-dt / tau)``."""
    for i in range(y.shape[0]):
        y[i] += g * (u[i] - y[i])


# --------------------------------------------------------------------- dynamic state (dynamic_state.py)
@njit(cache=True)
def manoeuvre_gain(dt_s, tau_s):
    """Per-tick gain ``g = 1 - exp(-dt / tau)`` of each low-pass stage (0 when ``dt <= 0``)."""
    return 1.0 - math.exp(-dt_s / tau_s) if dt_s > 0.0 else 0.0


@njit(cache=True)
def manoeuvre_step(y1, y2, accel, g):
    """One tick of the two cascaded low-passes, in place on ``y1``, ``y2`` (channels,):
    ``y1 += g (a - y1); y2 += g (y1 - y2)``; a non-finite sample holds the first stage.

    Shared by :meth:`ManoeuvreFilter.step_pair` and the online estimator's compiled tick.
    """
    for k in range(accel.shape[0]):
        a = accel[k]
        if math.isfinite(a):
            y1[k] = y1[k] + g * (a - y1[k])
        y2[k] = y2[k] + g * (y1[k] - y2[k])


@njit(cache=True)
def state_machine_step(t_s, power, v_long, theta, dwell_s, idle_speed, started, state, cand, cand_since):
    """One tick of :class:`WheelStateMachine` for every wheel, in place on ``state`` (int8),
    ``cand`` (int8, candidate state) and ``cand_since`` (s, when the candidate appeared).

    Same rules as :func:`raw_state` plus the dwell; ``started`` False: first tick, the raw
    state is taken at once. Shared by :class:`WheelStateMachine` and the online estimator's
    compiled tick.
    """
    half = 0.5 * theta
    for i in range(state.shape[0]):
        p = power[i]
        v = v_long[i]
        cur = state[i]
        if p != p or v != v:  # non-finite: keep the state
            raw = cur
        elif abs(v) < idle_speed:
            raw = IDLE
        elif cur == TRACTION and p > half:  # hysteresis: leave traction below theta/2
            raw = TRACTION
        elif cur == BRAKING and p < -half:
            raw = BRAKING
        elif p > theta:
            raw = TRACTION
        elif p < -theta:
            raw = BRAKING
        else:
            raw = STEADY
        if not started:
            state[i] = raw
            cand[i] = raw
            continue
        if raw == cur:
            cand[i] = cur
        elif raw != cand[i]:  # a new candidate: its dwell starts now
            cand[i] = raw
            cand_since[i] = t_s
        if raw == cand[i] and raw != cur and t_s - cand_since[i] >= dwell_s:
            state[i] = raw


# --------------------------------------------------------------------- the online tick (online.py)
@njit(cache=True)
def measurements_tick(t_s, z_raw, row_valid, group_of_row, last_seen, angle, yaw_offset, any_alpha,
                      one_minus_alpha, z_f, prev_valid, z_out, use_out):
    """Rows used and measurements after yaw zeroing and the EMA pre-filters (eq. 6.12).

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
            z_out[k] = (z_raw[k] - yaw_offset[k] + math.pi) % TWO_PI - math.pi
    if any_alpha:
        for k in range(m):
            if use_out[k]:
                if not prev_valid[k]:  # first sample after a gap: restart the EMA
                    z_f[k] = z_out[k]
                else:
                    d = z_out[k] - z_f[k]
                    if angle[k]:
                        d = (d + math.pi) % TWO_PI - math.pi
                    z_f[k] = z_f[k] + one_minus_alpha[k] * d  # z = alpha z_prev + (1 - alpha) z_raw
            prev_valid[k] = use_out[k]
            z_out[k] = z_f[k]


@njit(cache=True)
def wheels_tick(t_s, dt, first, cam_ok, x, P, steer_state, wheel_xy, radius, omega_radps, dead_band_mps,
                lag_tau_s, lag_y, slip_memory, slip_memory_tau_s, slip_mem, accel_tau_s, accel_y1, accel_y2,
                theta, dwell_s, idle_speed, state, cand, cand_since, steer_out, v_long_out, slip_out):
    """Slip and dynamic state of every wheel after the EKF update (SYSTEM §7.1, §7.2).

    Writes ``steer_out``, ``v_long_out``, ``slip_out`` (N,) and advances the encoder lag
    (``lag_y``), the slip memory (``slip_mem``), the manoeuvre filter (``accel_y1/2``) and the
    state machine (``state``, ``cand``, ``cand_since``). ``first``: first tick (filters start at
    their input). Returns ``(sane, memory_dt)``: whether the filter state is sane (finite,
    speeds < MAX_SPEED_MPS, P diagonal < MAX_P_DIAG) and the seconds to add to the slip memory's
    age (``dt`` when every wheel contributed).
    """
    n_w = steer_state.shape[0]
    vx, vy, r = x[3], x[4], x[5]
    c = np.empty(n_w)
    s = np.empty(n_w)
    for i in range(n_w):  # v_long_i = (vx - r y_i) cos d_i + (vy + r x_i) sin d_i   (eq. 7.3-7.5)
        if steer_state[i] >= 0:
            steer_out[i] = x[steer_state[i]]
        c[i] = math.cos(steer_out[i])
        s[i] = math.sin(steer_out[i])
        v_long_out[i] = (vx - r * wheel_xy[i, 1]) * c[i] + (vy + r * wheel_xy[i, 0]) * s[i]
    # v_long through the encoder's lag, so it is in phase with the (filtered) encoder
    v_lag = v_long_out
    if lag_tau_s > 0.0:
        if first:
            for i in range(n_w):
                lag_y[i] = v_long_out[i]
        else:
            lag_step(lag_y, v_long_out, 1.0 - math.exp(-dt / lag_tau_s))
        v_lag = lag_y
    memory_dt = 0.0
    if cam_ok:
        for i in range(n_w):
            slip_out[i] = slip_ratio_scalar(omega_radps[i] * radius, v_lag[i], dead_band_mps)
        if slip_memory and dt > 0.0:  # remember the slip for a camera gap
            g = 1.0 - math.exp(-dt / slip_memory_tau_s)
            all_ok = True
            for i in range(n_w):
                if math.isfinite(slip_out[i]) and abs(v_long_out[i]) >= SLIP_MEMORY_MIN_SPEED_MPS:
                    s_c = min(max(slip_out[i], -SLIP_MEMORY_CLIP), SLIP_MEMORY_CLIP)
                    slip_mem[i] = slip_mem[i] + g * (s_c - slip_mem[i])
                else:
                    all_ok = False
            if all_ok:
                memory_dt = dt
    else:
        for i in range(n_w):
            slip_out[i] = np.nan  # no camera: slip is unobservable
    # manoeuvre acceleration (vibration filtered out) -> Power_i = a_long_i v_long_i
    accel = np.empty(2)
    accel[0] = x[6]
    accel[1] = x[7]
    if first or accel_tau_s <= 0.0:
        for j in range(2):  # (element loops: a slice assignment costs seconds of compile time)
            accel_y1[j] = accel[j]
            accel_y2[j] = accel[j]
    else:
        manoeuvre_step(accel_y1, accel_y2, accel, manoeuvre_gain(dt, accel_tau_s))
    r2 = r * r
    power = np.empty(n_w)
    for i in range(n_w):
        a_long = (accel_y2[0] - r2 * wheel_xy[i, 0]) * c[i] + (accel_y2[1] - r2 * wheel_xy[i, 1]) * s[i]
        power[i] = a_long * v_long_out[i]
    state_machine_step(t_s, power, v_long_out, theta, dwell_s, idle_speed, not first, state, cand, cand_since)
    # health: finite state, plausible speeds, bounded covariance
    p_max = -np.inf
    for i in range(x.shape[0]):
        d = P[i, i]
        if d != d:
            p_max = np.nan
            break
        p_max = max(p_max, d)
    x_finite = True
    for i in range(x.shape[0]):
        if not math.isfinite(x[i]):
            x_finite = False
    sane = (abs(vx) < MAX_SPEED_MPS and abs(vy) < MAX_SPEED_MPS and p_max < MAX_P_DIAG
            and math.isfinite(p_max) and x_finite)
    return sane, memory_dt
