"""Ground-truth slip and dynamic state per wheel (design §7.1, §7.2) from simulator truth."""

from __future__ import annotations

import numpy as np

from terrainml.estimation.dynamic_state import classify_states
from terrainml.estimation.slip import slip_ratio


def slip_sae(v_ang_mps: np.ndarray, v_long_mps: np.ndarray, dead_band_mps: float = 0.05) -> np.ndarray:
    """design §7.1 slip of true speeds: the estimator's own
    :func:`terrainml.estimation.slip.slip_ratio` (one definition for truth and estimate)."""
    return np.asarray(slip_ratio(v_ang_mps, v_long_mps, dead_band_mps))


def wheel_states(t_s: np.ndarray, power_m2ps3: np.ndarray, v_long_mps: np.ndarray, theta: float = 0.02,
                 min_dwell_s: float = 0.2, idle_speed_mps: float = 0.05) -> np.ndarray:
    """design §7.2 dynamic state codes (0 idle, 1 steady, 2 traction, 3 braking) per row and wheel.

    The estimator's own state machine (:func:`terrainml.estimation.dynamic_state.classify_states`:
    hysteresis at theta/2, idle below 0.05 m/s, dwell debounce) applied to true Power, so truth and
    estimate share one definition.

    Parameters
    ----------
    t_s : (n,) time; power_m2ps3, v_long_mps : (n, N).
    """
    codes = classify_states(t_s, power_m2ps3, v_long_mps, theta, min_dwell_s, idle_speed_mps)
    return codes.astype(np.int64)
