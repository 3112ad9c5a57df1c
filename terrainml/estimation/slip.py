"""Per-wheel longitudinal slip (design §7.1; thesis §7.1-7.2, eq. 7.1, 7.2, 7.7, 8.4-8.5).

::

    v_long_i = (vx - r y_i) cos delta_i + (vy + r x_i) sin delta_i     (EKF states, m/s)
    v_ang_i  = omega_raw_i * R                                         (raw encoder, m/s)
    s_i = 0                                             if |v_ang_i| < 0.05 and |v_long_i| < 0.05
    s_i = clip((v_ang_i - v_long_i) / max(|v_ang_i|, |v_long_i|), -1, 1)   otherwise

The SAE split definition (traction: divide by |v_ang|; braking: divide by |v_long|) is the
division by the larger magnitude. Positive slip = traction when driving forward (SAE).

All functions are vectorised (numpy broadcasting) and are used unchanged per tick (arrays of N
wheels) and offline (arrays of shape (n_ticks, N)), so online and offline results are identical.
"""

from __future__ import annotations

import numpy as np

DEAD_BAND_MPS = 0.05


def wheel_v_long(vx_mps, vy_mps, yaw_rate_radps, steer_rad, wheel_x_m, wheel_y_m):
    """Longitudinal velocity of each wheel centre along its heading (eq. 7.3-7.5), m/s.

    Parameters broadcast: ``vx_mps``, ``vy_mps``, ``yaw_rate_radps`` shape (n,) or (n, 1) or
    scalars; ``steer_rad`` shape (..., N); ``wheel_x_m``, ``wheel_y_m`` shape (N,).
    """
    u = np.asarray(vx_mps)[..., None] - np.asarray(yaw_rate_radps)[..., None] * np.asarray(wheel_y_m)
    w = np.asarray(vy_mps)[..., None] + np.asarray(yaw_rate_radps)[..., None] * np.asarray(wheel_x_m)
    d = np.asarray(steer_rad, dtype=float)
    return u * np.cos(d) + w * np.sin(d)


def slip_ratio(v_ang_mps, v_long_mps, dead_band_mps: float = DEAD_BAND_MPS):
    """SAE longitudinal slip with dead band and saturation (design §7.1).

    Parameters
    ----------
    v_ang_mps : array_like, wheel peripheral speed omega R (m/s).
    v_long_mps : array_like, wheel-centre longitudinal speed (m/s), same shape.
    dead_band_mps : both speeds below this magnitude -> slip 0.

    Returns
    -------
    ndarray (or float for scalar input), slip in [-1, 1]; NaN where an input is NaN.
    """
    va = np.asarray(v_ang_mps, dtype=float)
    vl = np.asarray(v_long_mps, dtype=float)
    denom = np.maximum(np.abs(va), np.abs(vl))  # eq. 7.7: max of the magnitudes
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.clip((va - vl) / denom, -1.0, 1.0)
    dead = (np.abs(va) < dead_band_mps) & (np.abs(vl) < dead_band_mps)
    s = np.where(dead, 0.0, s)
    return float(s) if s.ndim == 0 else s
