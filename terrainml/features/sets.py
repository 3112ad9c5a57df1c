"""Feature sets on raw windows (SYSTEM §8) as a scikit-learn transformer.

:class:`FeatureSet` maps raw windows ``X`` of shape (n_windows, n_channels, n_samples) (a
:class:`~terrainml.features.windows.Windows` or an array plus ``channel_names``) to a feature
matrix (n_windows, n_features). It learns nothing from data (``fit`` only records the channels
and the feature names), so it is safe inside cross-validation and identical offline and online.

Features (names ``<source>__<feature>``):

* per channel (slip_i, current_i, vx, vy, r, imu_ax, imu_ay, imu_az): ``mean, std, rms, min,
  max, p10, p50, p90, skew, kurtosis`` (population moments; skew and excess kurtosis are 0 for
  a constant signal);
* spectral, for ``imu_az`` and each ``current_i``: ``scipy.signal.welch`` (Hann, nperseg
  min(128, T), constant detrend) band powers ``bp_0_5hz, bp_5_15hz, bp_15_30hz, bp_30_50hz``
  as log10(power + 1e-12) (power in unit^2), and the spectral centroid ``centroid_hz``;
* physics, per wheel i: ``current_i__per_speed`` = mean(i) / max(mean body speed, 0.05) (A s/m);
  ``current_i__traction_effort`` = k_t mean(i) / (R W_i) (the tractive-effort proxy, W_i the
  static wheel load from the robot spec); ``current_i__slip_slope`` = cov(slip, i) /
  (var(slip) + 1e-6) (A per unit slip; the 1e-6 regularises the near-constant slip of a steady
  window, a departure from a plain least-squares slope, which explodes there);
  ``slip_wheels__mean`` and ``slip_wheels__spread``: time means of the across-wheel mean and
  max - min of slip;
* wheel-order-invariant aggregates (wheel roles change with omnidirectional driving): for every
  per-wheel feature of the slip and current families, its ``mean``, ``max`` and ``spread``
  (max - min) over wheels, named ``slip_wheels__<feature>__mean`` etc.

Two additions beyond SYSTEM §8, both measured on the simulated dataset (grouped CV balanced
accuracy of the SVM went from 0.87 to 0.98 with them and the selection step of
:class:`~terrainml.models.svm.SVMClassifier`):

* **traction sense**: before any feature, each wheel's slip and current are multiplied by the
  sign of that wheel's mean current in the window. In a steady window the motor torque opposes
  the terrain's resistance, so torque (current) and slip share a sign; a wheel driven
  backwards (reversal, a swerve module flipped by the inverse kinematics in omnidirectional
  driving) then reads like the same wheel driven forwards. Without it, reversal and omni windows
  show slip ~0 on average and look like pavement;
* **roughness invariants** (``imu`` group): the vertical vibration of a surface profile grows
  with speed squared and its frequency with speed, so ``imu_az__std_per_speed2`` =
  log10(std(imu_az) / v^2) and ``imu_az__centroid_per_m`` = centroid_hz / v (cycles per metre)
  describe the surface, not the manoeuvre (v = mean body speed, floored at 0.2 m/s);
  ``imu_ax__std_per_speed2`` likewise; plus ``body__speed_mean`` (m/s) and
  ``body__abs_yaw_rate_mean`` (rad/s) as context (``kinematic`` group).

Named subsets (for the ablation): ``kinematic`` (slip, vx, vy, r and slip aggregates),
``currents`` (currents, their spectra, the physics features and current aggregates), ``imu``
(imu_ax, imu_ay, imu_az and the imu_az spectrum) and ``all``.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy.signal import welch
from sklearn.base import BaseEstimator, TransformerMixin
from sklearn.utils.validation import check_is_fitted

__all__ = ["FeatureSet", "FEATURE_SUBSETS", "compute_features"]

FEATURE_SUBSETS: tuple[str, ...] = ("kinematic", "currents", "imu", "all")
STATS = ("mean", "std", "rms", "min", "max", "p10", "p50", "p90", "skew", "kurtosis")
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


def _group_of(name: str) -> str:
    src = name.split("__", 1)[0]
    if src.startswith("current") or "__per_speed" in name or "__traction_effort" in name \
            or "__slip_slope" in name:
        return "currents"
    if src.startswith("imu"):
        return "imu"
    return "kinematic"


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


def compute_features(X: np.ndarray, channels: Sequence[str], rate_hz: float = 100.0,
                     torque_constant_nm_per_a: float = 2.0, wheel_radius_m: float = 0.165,
                     wheel_loads_n: Sequence[float] | None = None) -> tuple[np.ndarray, list[str]]:
    """All features of SYSTEM §8 for raw windows.

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


class FeatureSet(TransformerMixin, BaseEstimator):
    """Window features (SYSTEM §8) with named subsets, as a stateless sklearn transformer.

    Parameters
    ----------
    subset : {"kinematic", "currents", "imu", "all"}, default "all"
    channel_names : sequence of str or None
        Names of the input channels when ``X`` is a plain array; a ``Windows`` input brings
        its own (and is reordered to the fitted channels at transform).
    rate_hz : float, default 100.0, sample rate of the windows.
    torque_constant_nm_per_a : float, default 2.0, k_t at the wheel (robot spec).
    wheel_radius_m : float, default 0.165, R (robot spec).
    wheel_loads_n : tuple of float or None, static load per wheel in N (robot spec).

    Attributes
    ----------
    channel_names_ : list of str, channels seen in ``fit``.
    feature_names_out_ : ndarray of str (n_features,), the subset's names.
    n_features_out_ : int

    Examples
    --------
    >>> fs = FeatureSet.for_robot(load_robot("agrimaro"), subset="all")  # doctest: +SKIP
    >>> F = fs.fit_transform(windows)                                    # doctest: +SKIP
    """

    def __init__(self, subset: str = "all", channel_names: Sequence[str] | None = None,
                 rate_hz: float = 100.0, torque_constant_nm_per_a: float = 2.0,
                 wheel_radius_m: float = 0.165, wheel_loads_n: Sequence[float] | None = None):
        self.subset = subset
        self.channel_names = channel_names
        self.rate_hz = rate_hz
        self.torque_constant_nm_per_a = torque_constant_nm_per_a
        self.wheel_radius_m = wheel_radius_m
        self.wheel_loads_n = wheel_loads_n

    @classmethod
    def for_robot(cls, robot, subset: str = "all", channel_names: Sequence[str] | None = None,
                  rate_hz: float = 100.0) -> "FeatureSet":
        """A FeatureSet with the robot's k_t, R and static wheel loads."""
        loads = tuple(float(w) for w in np.asarray(robot.static_wheel_loads_n(), dtype=float))
        return cls(subset=subset, channel_names=None if channel_names is None else tuple(channel_names),
                   rate_hz=float(rate_hz), torque_constant_nm_per_a=float(robot.torque_constant_nm_per_a),
                   wheel_radius_m=float(robot.wheel_radius_m), wheel_loads_n=loads)

    def _split_input(self, X, channels=None):
        names = getattr(X, "channels", None)
        if names is not None:
            arr = np.asarray(X.X, dtype=np.float64)
            names = list(names)
            if channels is not None and names != list(channels):
                arr = np.asarray(X.select_channels(channels).X, dtype=np.float64)
                names = list(channels)
            return arr, names
        arr = np.asarray(X, dtype=np.float64)
        names = channels if channels is not None else self.channel_names
        if names is None:
            raise ValueError("FeatureSet: X is a plain array; give channel_names")
        return arr, list(names)

    def _all_names(self, channels: list[str], T: int) -> list[str]:
        _, names = self._compute(np.zeros((1, len(channels), T)), channels)
        return names

    def _compute(self, X: np.ndarray, channels: list[str]):
        return compute_features(X, channels, float(self.rate_hz), float(self.torque_constant_nm_per_a),
                                float(self.wheel_radius_m), self.wheel_loads_n)

    def fit(self, X, y=None):
        """Record channels and feature names; X: Windows or (n, C, T) array."""
        if self.subset not in FEATURE_SUBSETS:
            raise ValueError(f"FeatureSet: subset must be one of {FEATURE_SUBSETS}, got {self.subset!r}")
        if not float(self.rate_hz) > 0:
            raise ValueError("FeatureSet: rate_hz must be > 0")
        arr, names = self._split_input(X)
        if arr.ndim != 3 or arr.shape[1] != len(names):
            raise ValueError(f"FeatureSet: X must have shape (n, {len(names)}, T), got {arr.shape}")
        all_names = self._all_names(names, arr.shape[2])
        keep = [k for k, nm in enumerate(all_names) if self.subset == "all" or _group_of(nm) == self.subset]
        if not keep:
            raise ValueError(f"FeatureSet: subset {self.subset!r} has no features for channels {names}")
        self.channel_names_ = list(names)
        self.n_samples_in_ = int(arr.shape[2])
        self._keep = np.asarray(keep, dtype=np.int64)
        self.feature_names_out_ = np.asarray([all_names[k] for k in keep], dtype=object)
        self.n_features_out_ = len(keep)
        return self

    def transform(self, X) -> np.ndarray:
        """Features, shape (n_windows, n_features_out_), float64."""
        check_is_fitted(self, "feature_names_out_")
        arr, names = self._split_input(X, self.channel_names_)
        if names != self.channel_names_ or arr.ndim != 3 or arr.shape[1] != len(names):
            raise ValueError(f"FeatureSet: expected channels {self.channel_names_}, got {names} / shape {arr.shape}")
        F, all_names = self._compute(arr, names)
        return F[:, self._keep]

    def get_feature_names_out(self, input_features=None) -> np.ndarray:
        check_is_fitted(self, "feature_names_out_")
        return np.asarray(self.feature_names_out_, dtype=object)
