"""Feature sets on raw windows (design §8) as a scikit-learn transformer.

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

Two additions beyond design §8, both measured on the simulated dataset (grouped CV balanced
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

Implementation (one set of numbers, fast for the stream's one window per call): every statistic
is one whole-array numpy operation over all windows and channels at once, written into one flat
buffer laid out by :mod:`terrainml.features.feature_layout` (built once per channel list and
window length). The Welch spectrum agrees with ``scipy.signal.welch`` to ~1e-14 relative (a test
checks it). A window with a non-finite sample goes through ``np.percentile``/``min``/``max`` so
that NaN propagates exactly as there. Asked for a subset of the columns (the SVM's
selected features), only what those need is computed.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Sequence

import numpy as np
from sklearn.base import BaseEstimator, TransformerMixin
from sklearn.exceptions import NotFittedError
from sklearn.utils.validation import check_is_fitted

from terrainml.features.feature_layout import (AGGREGATES as AGGREGATES, BANDS_HZ as BANDS_HZ,
                                               PERCENTILES as PERCENTILES, PHYSICS as PHYSICS,
                                               SPECTRAL as SPECTRAL, STATS as STATS,
                                               WELCH_NPERSEG as WELCH_NPERSEG, FeatureLayout, columns_needed,
                                               feature_layout, feature_names as feature_names, sense_source)

__all__ = ["FeatureSet", "FEATURE_SUBSETS", "compute_features", "feature_names", "traction_sense"]

FEATURE_SUBSETS: tuple[str, ...] = ("kinematic", "currents", "imu", "all")
MIN_SPEED_MPS = 0.05
ROUGHNESS_MIN_SPEED_MPS = 0.2
SLOPE_RIDGE = 1e-6

_add = np.add.reduce
_max = np.maximum.reduce
_min = np.minimum.reduce


def _sense_flips(X: np.ndarray, mean: np.ndarray, sense: tuple, finite: bool) -> np.ndarray | None:
    """(n, C) bool: the channels of each window whose sign the traction sense changes (None: none).

    X : (n, C, T); mean : (n, C) time means of X; sense : :func:`sense_source`;
    finite : whether every mean is finite (else NaN samples are skipped, as ``nanmean``).
    A wheel whose mean current is 0 or NaN is left as is.
    """
    src, flippable, cur = sense
    if not cur.size:
        return None
    if not finite:
        mean = mean.copy()
        with np.errstate(invalid="ignore"):
            mean[:, cur] = np.nanmean(X[:, cur], axis=2)
    flip = (mean[:, src] < 0) & flippable
    return flip if flip.any() else None


def traction_sense(X: np.ndarray, channels: Sequence[str]) -> np.ndarray:
    """Copy of X with each wheel's slip and current multiplied by the sign of its mean current.

    X : (n, C, T). Wheels are paired by index (``slip_i`` with ``current_i``); a wheel without a
    current channel, or with a mean current of exactly 0, is left as is.
    """
    X = np.array(X, dtype=np.float64, copy=True)
    mean = _add(X, axis=-1) / X.shape[-1]
    flip = _sense_flips(X, mean, sense_source(tuple(channels)), bool(np.isfinite(mean).all()))
    if flip is not None:
        np.negative(X, out=X, where=flip[..., None])
    return X


def _group_of(name: str) -> str:
    src = name.split("__", 1)[0]
    if src.startswith("current") or "__per_speed" in name or "__traction_effort" in name \
            or "__slip_slope" in name:
        return "currents"
    if src.startswith("imu"):
        return "imu"
    return "kinematic"


@lru_cache(maxsize=64)
def _effort_denominator(wheels: tuple[int, ...], loads: tuple | None, wheel_radius_m: float) -> np.ndarray:
    """R W_i per current wheel (W_i the static load of wheel i, 1 N where none is given)."""
    W = [loads[i - 1] if loads is not None and i - 1 < len(loads) else 1.0 for i in wheels]
    return wheel_radius_m * np.asarray(W, dtype=np.float64)


def _aggregate(A: np.ndarray, out: np.ndarray) -> None:
    """Mean, max and spread over wheels: A (n, N, k) -> out (n, k, 3)."""
    mx = _max(A, axis=1)
    out[..., 0] = _add(A, axis=1) / A.shape[1]
    out[..., 1] = mx
    out[..., 2] = mx - _min(A, axis=1)


def _flat_features(X: np.ndarray, lay: FeatureLayout, torque_constant_nm_per_a: float,
                   wheel_radius_m: float, wheel_loads_n: tuple | None,
                   columns: np.ndarray | None = None) -> np.ndarray:
    """Features of X (n, C, T) in the layout's buffer order, shape (n, lay.n_flat).

    ``columns`` (indices into ``lay.names``, None: all): only what these need is computed; the
    other buffer positions are left at 0. The steps write their blocks of one buffer in order:
    statistics, spectra, context, physics, aggregates.
    """
    n, C, T = X.shape
    if columns is None:
        need, spec_k = None, lay.spec_all
    else:
        need, spec_k = columns_needed(lay, np.ascontiguousarray(columns, dtype=np.intp).tobytes())
    has = (lambda token: True) if need is None else need.__contains__
    out = np.zeros((n, lay.n_flat))
    mean = _add(X, axis=-1) / T
    finite = bool(np.isfinite(mean).all())  # a finite mean <=> every sample finite (or overflow)
    flip = _sense_flips(X, mean, lay.sense, finite)
    if flip is not None:
        X = np.where(flip[..., None], -X, X)
        mean = np.where(flip, -mean, mean)  # exact: the mean of -x is -(mean of x)
    st, c, m2 = _stat_block(X, mean, lay, has, finite, out)
    sp = _spectral_block(X, lay, spec_k, out)
    speed = _context_block(X, lay, has, st, sp, out)
    ph = _physics_block(lay, has, mean, c, m2, speed, out, torque_constant_nm_per_a, wheel_radius_m,
                        wheel_loads_n)
    _aggregate_block(X, lay, has, st, sp, ph, out)
    return out


def _stat_block(X, mean, lay: FeatureLayout, has, finite: bool, out: np.ndarray):
    """Statistics of every channel into ``out``; returns the block (n, C, k), x - mean and m2."""
    n, C, T = X.shape
    st = out[:, :lay.o_spec].reshape(n, C, len(STATS))
    c = X - mean[..., None]
    c2 = c * c
    m2 = _add(c2, axis=-1) / T
    st[..., 0] = mean
    st[..., 1] = np.sqrt(m2)
    if has("rms"):
        st[..., 2] = np.sqrt(_add(X * X, axis=-1) / T)
    if has("sort"):
        if finite:  # order statistics read from the sorted window
            g = np.sort(X, axis=-1).take(lay.sort_idx, axis=-1)  # min, max, lo x3, hi x3, base x3
            st[..., 3:5] = g[..., :2]
            st[..., 5:8] = g[..., 8:11] + (g[..., 5:8] - g[..., 2:5]) * lay.pct_coef
        else:  # NaN/inf present: numpy's own reductions (NaN propagates)
            st[..., 3] = X.min(axis=-1)
            st[..., 4] = X.max(axis=-1)
            st[..., 5:8] = np.moveaxis(np.percentile(X, PERCENTILES, axis=-1), 0, -1)
    if has("m34"):
        m3 = _add(c2 * c, axis=-1) / T
        m4 = _add(c2 * c2, axis=-1) / T
        tiny = m2 <= 1e-24 * (1.0 + mean * mean)  # constant signal: skew and kurtosis 0
        if tiny.any():
            safe = np.where(tiny, 1.0, m2)
            st[..., 8] = np.where(tiny, 0.0, m3 / safe ** 1.5)
            st[..., 9] = np.where(tiny, 0.0, m4 / safe ** 2 - 3.0)
        else:
            st[..., 8] = m3 / m2 ** 1.5
            st[..., 9] = m4 / m2 ** 2 - 3.0
    return st, c, m2


def _spectral_block(X, lay: FeatureLayout, spec_k, out: np.ndarray) -> np.ndarray:
    """Welch spectra (imu_az, currents): band powers (log10) and centroid; returns the block."""
    n = X.shape[0]
    sp = out[:, lay.o_spec:lay.o_ctx].reshape(n, lay.spec_pos.size, len(SPECTRAL))
    n_spec = len(lay.spec_pos[spec_k])
    if n_spec:
        seg = X[:, lay.spec_pos[spec_k][:, None, None], lay.seg_idx]  # (n, S, n_seg, nperseg)
        seg = seg - _add(seg, axis=-1, keepdims=True) / seg.shape[-1]  # detrend="constant"
        Z = seg @ lay.dft  # [Re, Im] of rfft(seg * window)
        R = (Z * Z).reshape(n, n_spec, -1) @ lay.band_matrix
        total = R[..., 5]  # R (n, S, 6): band sums, sum(P f), sum(P)
        cent = R[..., 4] / total if (total > 0).all() else \
            np.where(total > 0, R[..., 4] / np.where(total > 0, total, 1.0), 0.0)
        sp[:, spec_k, :4] = np.log10(R[..., :4] * lay.df_hz + 1e-12)
        sp[:, spec_k, 4] = cent
    return sp


def _context_block(X, lay: FeatureLayout, has, st, sp, out: np.ndarray):
    """Context: body speed, yaw rate, roughness invariants; returns the mean speed (or None)."""
    T = X.shape[-1]
    speed = None
    ctx = out[:, lay.o_ctx:lay.o_phys]
    if lay.ctx_yaw >= 0 and has("yaw"):
        ctx[:, lay.ctx_yaw] = _add(np.abs(X[:, lay.r]), axis=-1) / T
    if lay.vx >= 0 and lay.vy >= 0 and has("speed"):
        speed = _add(np.hypot(X[:, lay.vx], X[:, lay.vy]), axis=-1) / T
        ctx[:, 0] = speed
        v = np.maximum(speed, ROUGHNESS_MIN_SPEED_MPS)
        if lay.ctx_rough >= 0 and has("rough"):
            nr = lay.rough_pos.size
            ctx[:, lay.ctx_rough:lay.ctx_rough + nr] = np.log10(st[:, lay.rough_pos, 1] / (v ** 2)[:, None]
                                                                 + 1e-9)
        if lay.ctx_cpm >= 0 and has("cpm"):
            ctx[:, lay.ctx_cpm] = sp[:, lay.az_spec, 4] / v
    return speed


def _physics_block(lay: FeatureLayout, has, mean, c, m2, speed, out: np.ndarray, torque_constant_nm_per_a: float,
                   wheel_radius_m: float, wheel_loads_n: tuple | None) -> np.ndarray:
    """Physics per wheel (current per speed, effort, current-slip slope); returns the block."""
    n, T = out.shape[0], c.shape[-1]
    Nc = lay.cur_pos.size
    ph = out[:, lay.o_phys:lay.o_slipw].reshape(n, Nc, len(PHYSICS))
    if Nc and has("phys"):
        mean_i = mean[:, lay.cur_pos]
        if speed is not None:
            ph[..., 0] = mean_i / np.maximum(speed, MIN_SPEED_MPS)[:, None]
        ph[..., 1] = torque_constant_nm_per_a * mean_i / _effort_denominator(
            lay.cur_wheel, wheel_loads_n, wheel_radius_m)
    if lay.slope_cur.size and has("slope"):
        cov = _add(c[:, lay.slope_slip] * c[:, lay.cur_pos[lay.slope_cur]], axis=-1) / T
        ph[:, lay.slope_cur, 2] = cov / (m2[:, lay.slope_slip] + SLOPE_RIDGE)
    return ph


def _aggregate_block(X, lay: FeatureLayout, has, st, sp, ph, out: np.ndarray) -> None:
    """Slip across wheels, and wheel-order-invariant aggregates (mean, max, spread over wheels)."""
    n, T = X.shape[0], X.shape[-1]
    Nc, Ns = lay.cur_pos.size, lay.slip_pos.size
    if Ns and (has("slipw_mean") or has("slipw_spread")):
        Sw = X[:, lay.slip_pos]  # (n, N, T)
        if has("slipw_mean"):
            out[:, lay.o_slipw] = _add(_add(Sw, axis=1) / Ns, axis=-1) / T
        if has("slipw_spread"):
            out[:, lay.o_slipw + 1] = _add(_max(Sw, axis=1) - _min(Sw, axis=1), axis=-1) / T
    agg_slip, agg_cur = Ns and has("agg_slip"), Nc and has("agg_cur")
    if agg_slip and agg_cur and Ns == Nc:  # adjacent blocks: one pass over [slip keys, current keys]
        A = np.concatenate((st[:, lay.slip_pos], st[:, lay.cur_pos], sp[:, lay.cur_spec],
                            ph[..., lay.cur_agg_phys]), axis=2)
        _aggregate(A, out[:, lay.o_agg_slip:].reshape(n, A.shape[2], 3))
    else:
        if agg_slip:
            _aggregate(st[:, lay.slip_pos], out[:, lay.o_agg_slip:lay.o_agg_cur].reshape(n, len(STATS), 3))
        if agg_cur:
            A = np.concatenate((st[:, lay.cur_pos], sp[:, lay.cur_spec], ph[..., lay.cur_agg_phys]), axis=2)
            _aggregate(A, out[:, lay.o_agg_cur:].reshape(n, A.shape[2], 3))


def _check_input(X, channels) -> tuple[np.ndarray, tuple[str, ...]]:
    X = np.asarray(X, dtype=np.float64)
    channels = tuple(channels)
    if X.ndim != 3 or X.shape[1] != len(channels):
        raise ValueError(f"features: X must have shape (n, {len(channels)}, T), got {X.shape}")
    return X, channels


def _loads_key(wheel_loads_n) -> tuple | None:
    return None if wheel_loads_n is None else tuple(float(w) for w in np.ravel(wheel_loads_n))


def compute_features(X: np.ndarray, channels: Sequence[str], rate_hz: float = 100.0,
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
    X, channels = _check_input(X, channels)
    lay = feature_layout(channels, int(X.shape[2]), float(rate_hz))
    flat = _flat_features(X, lay, float(torque_constant_nm_per_a), float(wheel_radius_m),
                          _loads_key(wheel_loads_n))
    return flat.take(lay.order, axis=1), list(lay.names)


class FeatureSet(TransformerMixin, BaseEstimator):
    """Window features (design §8) with named subsets, as a stateless sklearn transformer.

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
    >>> fs = FeatureSet.for_robot(robot, subset="all")  # robot: a RobotSpec  # doctest: +SKIP
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
        return feature_names(channels, T, float(self.rate_hz))

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
        return self._transform_columns(X, None)

    def _transform_columns(self, X, columns: np.ndarray | None) -> np.ndarray:
        """Columns ``columns`` (indices into the fitted features; None: all) of the features of X.

        The hot path of one-window classification (``SVMClassifier`` asks for its selected
        features only): no sklearn wrappers, only what those columns need is computed.
        """
        if not hasattr(self, "feature_names_out_"):
            raise NotFittedError("This FeatureSet instance is not fitted yet. Call 'fit' first.")
        arr, names = self._split_input(X, self.channel_names_)
        if names != self.channel_names_ or arr.ndim != 3 or arr.shape[1] != len(names):
            raise ValueError(f"FeatureSet: expected channels {self.channel_names_}, got {names} / shape {arr.shape}")
        lay = feature_layout(tuple(names), int(arr.shape[2]), float(self.rate_hz))
        cols = self._keep if columns is None else self._keep[columns]
        flat = _flat_features(arr, lay, float(self.torque_constant_nm_per_a), float(self.wheel_radius_m),
                              _loads_key(self.wheel_loads_n), None if self.subset == "all" and columns is None
                              else cols)
        return flat.take(lay.order[cols], axis=1)

    def get_feature_names_out(self, input_features=None) -> np.ndarray:
        check_is_fitted(self, "feature_names_out_")
        return np.asarray(self.feature_names_out_, dtype=object)
