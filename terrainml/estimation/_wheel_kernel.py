"""The per-wheel compiled (numba) kernels of the estimator: slip, dynamic state and the online
tick's wheel step (design §7.1, §7.2).

The per-tick rules as scalar loops (:func:`slip_ratio_scalar`, :func:`lag_step`,
:func:`manoeuvre_step`, :func:`state_machine_step`), called by the classes of :mod:`.slip` and
:mod:`.dynamic_state` and by the online tick's :func:`wheels_tick`, so each rule has one
implementation.

Self-contained on purpose: numba's on-disk cache only watches the file a kernel is defined in, so
a kernel here calls no compiled function and reads no constant of another file; the EKF's state
layout reaches :func:`wheels_tick` as an argument (``body_rows``).

``HAVE_NUMBA`` tells whether the compiled path is available; with ``TERRAINML_NO_NUMBA=1`` the
same functions run as plain Python (slow, same numbers).
"""
from __future__ import annotations

import math

import numpy as np

from terrainml._numba import HAVE_NUMBA, njit  # noqa: F401  (HAVE_NUMBA re-exported)

__all__ = ["IDLE", "STEADY", "TRACTION", "BRAKING", "MAX_SPEED_MPS", "MAX_P_DIAG", "SLIP_MEMORY_MIN_SPEED_MPS",
           "SLIP_MEMORY_CLIP", "slip_ratio_scalar", "lag_step", "manoeuvre_gain", "manoeuvre_step",
           "state_machine_step", "wheels_tick"]

# dynamic-state codes, in the order of schema.WHEEL_STATES (re-exported by dynamic_state)
IDLE, STEADY, TRACTION, BRAKING = range(4)
# online health and slip memory (re-exported by online)
MAX_SPEED_MPS = 50.0  # beyond this the filter is declared diverged
MAX_P_DIAG = 1e6
SLIP_MEMORY_MIN_SPEED_MPS = 0.2  # slip is remembered only where the wheel moves this fast
SLIP_MEMORY_CLIP = 0.95


# --------------------------------------------------------------------- slip (slip.py)
@njit(cache=True)
def slip_ratio_scalar(v_ang_mps, v_long_mps, dead_band_mps):
    """:func:`slip_ratio` for one wheel and plain floats (same maths; the per-tick path of the
    online estimator's compiled tick)."""
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

    Hysteresis (traction or braking is left only when Power crosses theta/2) plus the dwell;
    ``started`` False: first tick, the raw state is taken at once. Shared by
    :class:`WheelStateMachine` and the online estimator's compiled tick.
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


@njit(cache=True)
def wheels_tick(t_s, dt, first, cam_ok, x, body_rows, P, steer_state, wheel_xy, radius, omega_radps, dead_band_mps,
                lag_tau_s, lag_y, slip_memory, slip_memory_tau_s, slip_mem, accel_tau_s, accel_y1, accel_y2,
                theta, dwell_s, idle_speed, state, cand, cand_since, steer_out, v_long_out, slip_out):
    """Slip and dynamic state of every wheel after the EKF update (design §7.1, §7.2).

    Numba kernel: takes flat arrays and scalars, because numba compiles a call with plain arrays
    and numbers without boxing, and the online tick calls it every base period. ``body_rows``
    (int, (5,)): the rows of ``vx, vy, r, ax, ay`` in the EKF state ``x``.

    Writes ``steer_out``, ``v_long_out``, ``slip_out`` (N,) and advances the encoder lag
    (``lag_y``), the slip memory (``slip_mem``), the manoeuvre filter (``accel_y1/2``) and the
    state machine (``state``, ``cand``, ``cand_since``). ``first``: first tick (filters start at
    their input). Returns ``(sane, memory_dt)``: whether the filter state is sane (finite,
    speeds < MAX_SPEED_MPS, P diagonal < MAX_P_DIAG) and the seconds to add to the slip memory's
    age (``dt`` when every wheel contributed).
    """
    n_w = steer_state.shape[0]
    vx, vy, r = x[body_rows[0]], x[body_rows[1]], x[body_rows[2]]
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
    accel[0] = x[body_rows[3]]
    accel[1] = x[body_rows[4]]
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
