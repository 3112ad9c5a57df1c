"""Reference implementation of the window features (design §8), for tests only.

A straightforward per-channel transcription of the feature definitions with
``scipy.signal.welch`` and ``np.percentile``: the implementation ``terrainml.features.sets``
replaced with a vectorised one. The tests check the fast code against it (and against scipy
directly); it is kept simple on purpose and is not imported by the package.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy.signal import welch

BANDS_HZ = ((0.0, 5.0), (5.0, 15.0), (15.0, 30.0), (30.0, 50.0))
MIN_SPEED_MPS = 0.05
ROUGHNESS_MIN_SPEED_MPS = 0.2
SLOPE_RIDGE = 1e-6


def traction_sense(X: np.ndarray, channels: Sequence[str]) -> np.ndarray:
    """Copy of X with each wheel's slip and current multiplied by the sign of its mean current.

    X : (n, C, T). Wheels are paired by index (``slip_i`` with ``current_i``); a wheel without a
    current channel, or with a mean current of exactly 0, is left as is.
    """
    X = np.array(X, dtype=np.float64, copy=True)
    pos = {c: k for k, c in enumerate(channels)}
    for c in channels:
        if not c.startswith("current_"):
            continue
        i = c[len("current_"):]
        with np.errstate(invalid="ignore"):
            sign = np.where(np.nanmean(X[:, pos[c]], axis=1) < 0, -1.0, 1.0)  # 0 or NaN: as is
        X[:, pos[c]] *= sign[:, None]
        if f"slip_{i}" in pos:
            X[:, pos[f"slip_{i}"]] *= sign[:, None]
    return X


def _stats(x: np.ndarray) -> dict[str, np.ndarray]:
    """Ten statistics over the last axis of x (..., T)."""
    mean = x.mean(axis=-1)
    c = x - mean[..., None]
    c2 = c * c
    m2 = c2.mean(axis=-1)
    m3 = (c2 * c).mean(axis=-1)
    m4 = (c2 * c2).mean(axis=-1)
    tiny = m2 <= 1e-24 * (1.0 + mean * mean)
    safe = np.where(tiny, 1.0, m2)
    p10, p50, p90 = np.percentile(x, [10.0, 50.0, 90.0], axis=-1)
    return {
        "mean": mean, "std": np.sqrt(m2), "rms": np.sqrt((x * x).mean(axis=-1)),
        "min": x.min(axis=-1), "max": x.max(axis=-1), "p10": p10, "p50": p50, "p90": p90,
        "skew": np.where(tiny, 0.0, m3 / safe ** 1.5),
        "kurtosis": np.where(tiny, 0.0, m4 / safe ** 2 - 3.0),
    }


def _spectral(x: np.ndarray, rate_hz: float) -> dict[str, np.ndarray]:
    """Welch band powers (log10) and spectral centroid over the last axis of x (..., T)."""
    T = x.shape[-1]
    f, P = welch(x, fs=rate_hz, nperseg=min(128, T), detrend="constant", axis=-1)
    df = f[1] - f[0] if f.size > 1 else 1.0
    out = {}
    for k, (lo, hi) in enumerate(BANDS_HZ):
        last = k == len(BANDS_HZ) - 1
        sel = (f >= lo) & ((f <= hi) if last else (f < hi))
        out[f"bp_{lo:g}_{hi:g}hz"] = np.log10(P[..., sel].sum(axis=-1) * df + 1e-12)
    total = P.sum(axis=-1)
    out["centroid_hz"] = np.where(total > 0, (P * f).sum(axis=-1) / np.where(total > 0, total, 1.0), 0.0)
    return out


def reference_features(X: np.ndarray, channels: Sequence[str], rate_hz: float = 100.0,
                     torque_constant_nm_per_a: float = 2.0, wheel_radius_m: float = 0.165,
                     wheel_loads_n: Sequence[float] | None = None) -> tuple[np.ndarray, list[str]]:
    """All features of design §8 for raw windows.

    Parameters
    ----------
    X : ndarray (n_windows, n_channels, n_samples), channel units (slip -, A, m/s, rad/s, m/s^2).
    channels : names of the n_channels channels.
    rate_hz : sample rate in Hz.
    torque_constant_nm_per_a, wheel_radius_m : robot constants k_t (N m/A) and R (m).
    wheel_loads_n : static load per wheel in N (None: the traction-effort proxy uses 1 N).

    Returns
    -------
    F : ndarray (n_windows, n_features), float64.
    names : list of str, feature names in column order.
    """
    X = np.asarray(X, dtype=np.float64)
    channels = list(channels)
    if X.ndim != 3 or X.shape[1] != len(channels):
        raise ValueError(f"features: X must have shape (n, {len(channels)}, T), got {X.shape}")
    n = X.shape[0]
    X = traction_sense(X, channels)
    pos = {c: k for k, c in enumerate(channels)}
    st_all = _stats(X)  # name -> (n, C)
    spec_ch = [c for c in channels if c.startswith("current_") or c == "imu_az"]
    sp_all = _spectral(X[:, [pos[c] for c in spec_ch], :], rate_hz) if spec_ch else {}
    spos = {c: k for k, c in enumerate(spec_ch)}
    cols: dict[str, np.ndarray] = {}
    per_wheel: dict[str, dict[int, dict[str, np.ndarray]]] = {"slip": {}, "current": {}}
    for c in channels:
        st = {k: v[:, pos[c]] for k, v in st_all.items()}
        if c in spos:
            st.update({k: v[:, spos[c]] for k, v in sp_all.items()})
        for k, v in st.items():
            cols[f"{c}__{k}"] = v
        if c.startswith("slip_"):
            per_wheel["slip"][int(c[5:])] = st
        elif c.startswith("current_"):
            per_wheel["current"][int(c[8:])] = st
    slip_w = sorted((int(c[5:]), c) for c in channels if c.startswith("slip_"))
    cur_w = sorted((int(c[8:]), c) for c in channels if c.startswith("current_"))
    # physics
    if "vx" in pos and "vy" in pos:
        speed = np.hypot(X[:, pos["vx"]], X[:, pos["vy"]]).mean(axis=1)
        cols["body__speed_mean"] = speed
        if "r" in pos:
            cols["body__abs_yaw_rate_mean"] = np.abs(X[:, pos["r"]]).mean(axis=1)
        v = np.maximum(speed, ROUGHNESS_MIN_SPEED_MPS)
        for c in ("imu_az", "imu_ax"):
            if c in pos:
                cols[f"{c}__std_per_speed2"] = np.log10(st_all["std"][:, pos[c]] / v ** 2 + 1e-9)
        if "imu_az" in spos:
            cols["imu_az__centroid_per_m"] = sp_all["centroid_hz"][:, spos["imu_az"]] / v
    else:
        speed = None
    loads = None if wheel_loads_n is None else np.asarray(wheel_loads_n, dtype=np.float64)
    slips = dict(slip_w)
    for i, c in cur_w:
        cur = X[:, pos[c]]
        mean_i = st_all["mean"][:, pos[c]]
        phys = {}
        if speed is not None:
            phys["per_speed"] = mean_i / np.maximum(speed, MIN_SPEED_MPS)
        W = loads[i - 1] if loads is not None and i - 1 < len(loads) else 1.0
        phys["traction_effort"] = torque_constant_nm_per_a * mean_i / (wheel_radius_m * W)
        if i in slips:
            s = X[:, pos[slips[i]]]
            sc = s - st_all["mean"][:, pos[slips[i]], None]
            ic = cur - mean_i[:, None]
            phys["slip_slope"] = (sc * ic).mean(axis=1) / ((sc * sc).mean(axis=1) + SLOPE_RIDGE)
        for k, v in phys.items():
            cols[f"{c}__{k}"] = v
        per_wheel["current"][i].update(phys)
    if slip_w:
        S = X[:, [pos[c] for _, c in slip_w], :]  # (n, N, T)
        cols["slip_wheels__mean"] = S.mean(axis=1).mean(axis=1)
        cols["slip_wheels__spread"] = (S.max(axis=1) - S.min(axis=1)).mean(axis=1)
    # wheel-order-invariant aggregates
    for fam in ("slip", "current"):
        wheels = per_wheel[fam]
        if not wheels:
            continue
        keys = list(next(iter(wheels.values())).keys())
        A = np.stack([np.stack([wheels[i][k] for k in keys], axis=-1) for i in sorted(wheels)],
                     axis=-1)  # (n, n_keys, N)
        mean, mx, mn = A.mean(axis=-1), A.max(axis=-1), A.min(axis=-1)
        for j, k in enumerate(keys):
            cols[f"{fam}_wheels__{k}__mean"] = mean[:, j]
            cols[f"{fam}_wheels__{k}__max"] = mx[:, j]
            cols[f"{fam}_wheels__{k}__spread"] = mx[:, j] - mn[:, j]
    names = list(cols)
    F = np.stack([cols[k] for k in names], axis=1) if names else np.zeros((n, 0))
    return F, names
