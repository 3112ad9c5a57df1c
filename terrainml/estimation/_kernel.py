"""Compiled (numba) versions of :meth:`Ekf.predict` and :meth:`Ekf.update` (optional speed-up).

Same equations, written as explicit loops so numba can compile them; the numpy methods of
:class:`terrainml.estimation.ekf.Ekf` remain the readable reference and the fallback when numba
is not installed. A test checks both paths agree to 1e-9 over a whole run.

``HAVE_NUMBA`` tells whether the compiled path is available; set the environment variable
``TERRAINML_NO_NUMBA=1`` to force the numpy path.
"""

from __future__ import annotations

import math

import numpy as np

from terrainml._numba import HAVE_NUMBA, njit  # noqa: F401  (HAVE_NUMBA re-exported)

TWO_PI = 2.0 * math.pi


@njit(cache=True)
def _wrap(a):
    w = (a + math.pi) % TWO_PI - math.pi
    return math.pi if w == -math.pi else w


@njit(cache=True)
def predict_kernel(x, P, Q0, dt, q_scale, F, tmp):
    """x = f(x); P = F P F^T + Q0 q_scale. ``F`` (n, n) identity work array, ``tmp`` (n, n)."""
    n = x.shape[0]
    c = math.cos(x[2])
    s = math.sin(x[2])
    vx, vy, r = x[3], x[4], x[5]
    # Jacobian at the prior mean (see ekf.fill_F)
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
    x[0] += dt * (vx * c - vy * s)
    x[1] += dt * (vx * s + vy * c)
    x[2] = _wrap(x[2] + dt * r)
    x[3] = vx + dt * (x[6] + r * vy)
    x[4] = vy + dt * (x[7] - r * vx)
    # tmp = F P
    for i in range(n):
        for j in range(n):
            acc = 0.0
            for k in range(n):
                acc += F[i, k] * P[k, j]
            tmp[i, j] = acc
    # P = tmp F^T + Q
    for i in range(n):
        for j in range(n):
            acc = 0.0
            for k in range(n):
                acc += tmp[i, k] * F[j, k]
            P[i, j] = acc + Q0[i, j] * q_scale


@njit(cache=True)
def update_kernel(x, P, H_all, z, use, r_diag, angle, gated_rows, gate, release, n_wheel_rows,
                  wheel_xy, steer_state, radius, y_out, s_out):
    """Joseph-form update (see Ekf.update). Returns (nis, dof, n_bad, gated_now, agree).

    ``gate`` <= 0 disables the gate; ``release`` True keeps gated rows (gate released).
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
    # ---- rows used, innovations
    idx = np.empty(m, dtype=np.int64)
    k = 0
    for i in range(m):
        if use[i]:
            idx[k] = i
            k += 1
    yv = np.empty(m)
    for a in range(k):
        i = idx[a]
        if i < n_wheel_rows:
            h = H_all[i, 3] * x[3] + H_all[i, 4] * x[4] + H_all[i, 5] * x[5]
        else:
            h = 0.0
            for j in range(n):
                h += H_all[i, j] * x[j]
        yy = z[i] - h
        if angle[i]:
            yy = (yy + math.pi) % TWO_PI - math.pi
        yv[i] = yy
    # ---- S diagonal for the gate: S_ii = H_i P H_i^T + R_i
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
                for p in range(n):
                    hp = 0.0
                    for q in range(n):
                        hp += H_all[i, q] * P[q, p]
                    sii += hp * H_all[i, p]
                if yv[i] * yv[i] > gate * sii:
                    bad = True
            if bad:
                agree = False
                if not release:
                    n_bad += 1
                    continue
            idx[keep] = i
            keep += 1
        if n_bad > 0:
            gated_now = True
        k = keep
    if k == 0:
        return np.nan, 0, n_bad, gated_now, agree
    # ---- HP (k, n), S (k, k)
    HP = np.empty((k, n))
    for a in range(k):
        i = idx[a]
        for p in range(n):
            acc = 0.0
            for q in range(n):
                acc += H_all[i, q] * P[q, p]
            HP[a, p] = acc
    S = np.empty((k, k))
    for a in range(k):
        for b in range(k):
            acc = 0.0
            ib = idx[b]
            for p in range(n):
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
                    return np.nan, -1, n_bad, gated_now, agree  # not PD: caller falls back
                L[a, a] = math.sqrt(acc)
            else:
                L[a, b] = acc / L[b, b]
    # ---- solve S X = [HP | y]  ->  X[:, :n] = K^T, X[:, n] = S^-1 y
    X = np.empty((k, n + 1))
    for a in range(k):
        for p in range(n):
            X[a, p] = HP[a, p]
        X[a, n] = yv[idx[a]]
    for col in range(n + 1):
        for a in range(k):  # forward: L w = b
            acc = X[a, col]
            for c2 in range(a):
                acc -= L[a, c2] * X[c2, col]
            X[a, col] = acc / L[a, a]
        for a in range(k - 1, -1, -1):  # backward: L^T v = w
            acc = X[a, col]
            for c2 in range(a + 1, k):
                acc -= L[c2, a] * X[c2, col]
            X[a, col] = acc / L[a, a]
    # ---- x = x + K y
    for p in range(n):
        acc = 0.0
        for a in range(k):
            acc += X[a, p] * yv[idx[a]]
        x[p] += acc
    x[2] = _wrap(x[2])
    # ---- Joseph: A = I - K H; P = A P A^T + K R K^T
    A = np.empty((n, n))
    for p in range(n):
        for q in range(n):
            acc = 0.0
            for a in range(k):
                acc += X[a, p] * H_all[idx[a], q]
            A[p, q] = (1.0 if p == q else 0.0) - acc
    T = np.empty((n, n))
    for p in range(n):
        for q in range(n):
            acc = 0.0
            for c2 in range(n):
                acc += A[p, c2] * P[c2, q]
            T[p, q] = acc
    for p in range(n):
        for q in range(p, n):
            acc = 0.0
            for c2 in range(n):
                acc += T[p, c2] * A[q, c2]
            kr = 0.0
            for a in range(k):
                kr += X[a, p] * r_diag[idx[a]] * X[a, q]
            v = acc + kr
            P[p, q] = v
    for p in range(n):
        for q in range(p):
            P[p, q] = P[q, p]
    nis = 0.0
    for a in range(k):
        nis += yv[idx[a]] * X[a, n]
        y_out[idx[a]] = yv[idx[a]]
        s_out[idx[a]] = S[a, a]
    return nis, k, n_bad, gated_now, agree
