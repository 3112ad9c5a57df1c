"""Ground-truth slip and dynamic state per wheel (SYSTEM §7.1, §7.2) from simulator truth."""

from __future__ import annotations

import numpy as np

from terrainml.io.topics import WHEEL_STATE_CODES

IDLE, STEADY, TRACTION, BRAKING = (WHEEL_STATE_CODES[k] for k in ("idle", "steady", "traction", "braking"))


def slip_sae(v_ang_mps: np.ndarray, v_long_mps: np.ndarray, dead_band_mps: float = 0.05) -> np.ndarray:
    """SYSTEM §7.1 slip: clip((v_ang - v_long) / max(|v_ang|, |v_long|), -1, 1), 0 in the dead band."""
    va = np.asarray(v_ang_mps, dtype=float)
    vl = np.asarray(v_long_mps, dtype=float)
    den = np.maximum(np.abs(va), np.abs(vl))
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.clip((va - vl) / np.where(den > 0, den, 1.0), -1.0, 1.0)
    return np.where((np.abs(va) < dead_band_mps) & (np.abs(vl) < dead_band_mps), 0.0, s)


def wheel_states(t_s: np.ndarray, power_m2ps3: np.ndarray, v_long_mps: np.ndarray, theta: float = 0.02,
                 min_dwell_s: float = 0.2, idle_speed_mps: float = 0.05) -> np.ndarray:
    """SYSTEM §7.2 dynamic state codes (0 idle, 1 steady, 2 traction, 3 braking) per row and wheel.

    traction if P > theta, braking if P < -theta (leave at theta/2: hysteresis), idle when
    |v_long| < 0.05 m/s; a new state must persist ``min_dwell_s`` before it is taken.

    Parameters
    ----------
    t_s : (n,) time; power_m2ps3, v_long_mps : (n, N).
    """
    n, nw = power_m2ps3.shape
    out = np.empty((n, nw), dtype=np.int64)
    for i in range(nw):
        cur, cand, cand_t = STEADY, STEADY, -np.inf
        p = power_m2ps3[:, i]
        v = v_long_mps[:, i]
        for k in range(n):
            if abs(v[k]) < idle_speed_mps:
                raw = IDLE
            elif cur == TRACTION and p[k] > theta / 2:
                raw = TRACTION
            elif cur == BRAKING and p[k] < -theta / 2:
                raw = BRAKING
            elif p[k] > theta:
                raw = TRACTION
            elif p[k] < -theta:
                raw = BRAKING
            else:
                raw = STEADY
            if raw == cur:
                cand = cur
            elif raw != cand:
                cand, cand_t = raw, t_s[k]
            if raw == cand and raw != cur and (t_s[k] - cand_t >= min_dwell_s or k == 0):
                cur = raw
            if k == 0:
                cur = raw
                cand = raw
            out[k, i] = cur
    return out
