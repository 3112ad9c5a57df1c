"""Window features of a skid-steer robot without camera or steering (design §8).

:func:`side_channel_features` and its stateless transformer :class:`SideChannelFeatures` work
on the raw *side channels* of such a robot (BorealTC's Clearpath Husky): the six IMU channels,
and per side the motor current and the wheel rim speed. :class:`~terrainml.features.sets.
FeatureSet` is built around the canonical slip/vx/vy/r channels, which a camera-less robot
lacks, hence a second feature family. Channel names: ``imu_ax, imu_ay, imu_az`` (m/s^2),
``imu_wx, imu_wy, imu_wz`` (rad/s), ``current_left, current_right`` (A), ``speed_left_mps,
speed_right_mps`` (m/s); any subset works, the physics features need their channels.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy.signal import welch
from sklearn.base import BaseEstimator, TransformerMixin
from sklearn.utils.validation import check_is_fitted

from terrainml.features.sets import MIN_SPEED_MPS, ROUGHNESS_MIN_SPEED_MPS
from terrainml.features.windows import IMU_CHANNELS
from terrainml.robot import RobotSpec

__all__ = ["side_channel_features", "SideChannelFeatures", "SIDE_BANDS_HZ", "GYRO_CHANNELS",
           "HUSKY_TRACK_M", "track_of"]

GYRO_CHANNELS = ("imu_wx", "imu_wy", "imu_wz")
#: IMU channels that get the roughness invariants (accelerometer, then gyro)
ROUGHNESS_CHANNELS = IMU_CHANNELS + GYRO_CHANNELS
#: Welch band edges (Hz) of the log band powers (nine bands up to the 50 Hz Nyquist of 100 Hz
#: data; FeatureSet has four)
SIDE_BANDS_HZ = ((0.0, 1.0), (1.0, 3.0), (3.0, 6.0), (6.0, 10.0), (10.0, 15.0), (15.0, 20.0),
                 (20.0, 30.0), (30.0, 40.0), (40.0, 50.0))
#: left-right wheel distance B (m) of the Clearpath Husky, the default robot of this family
HUSKY_TRACK_M = 0.5708


def track_of(robot: RobotSpec) -> float:
    """Left-right wheel distance B (m): the spread of the wheels' lateral positions y, the track of
    a skid-steer robot (the Husky's when the robot's wheels all sit on its centre line, e.g. one
    wheel: a zero track would divide the yaw rate by zero)."""
    ys = [w.y_m for w in robot.wheels]
    spread = float(max(ys) - min(ys)) if ys else 0.0
    return spread if spread > 0 else HUSKY_TRACK_M


def side_channel_features(X: np.ndarray, channels: Sequence[str], rate_hz: float = 100.0,
                          track_m: float = HUSKY_TRACK_M, bands_hz=SIDE_BANDS_HZ,
                          correlations: bool = True) -> tuple[np.ndarray, list[str]]:
    """Window features for a skid-steer robot's raw side channels.

    Parameters
    ----------
    X : ndarray (n, C, T) in channel units (m/s^2, rad/s, A, m/s).
    channels : C names; the physics features use ``current_left/right``, ``speed_left/right_mps``
        and ``imu_wz`` when present.
    rate_hz : sample rate (Hz). track_m : left-right wheel distance B (m).
    bands_hz : Welch band edges (Hz) for the log band powers of every channel.
    correlations : add the Pearson correlation of every channel pair (C(C-1)/2 features).

    Returns
    -------
    F (n, n_features) float64 and the feature names.

    Features: per channel mean, std, min, max, p10, p50, p90, skew, excess kurtosis, mean
    absolute first difference (jerk proxy), log10 Welch band powers (Hann, nperseg min(64, T))
    and spectral centroid; channel-pair correlations; physics: left-right current difference
    and sum (mean, std), left-right speed difference, forward speed v = (vL + vR)/2, current
    per speed sum(i)/max(|v|, 0.05) per side and total, electrical power proxy i*v per side,
    and the skid indicator: measured yaw rate minus the kinematic one (vR - vL)/B (mean, std)
    and their ratio; roughness invariants for every IMU channel, log10 of std / v^2, std / v
    and mean |first difference| / v, plus log10 of the mean |total current| / v (v the mean
    forward speed floored at 0.2 m/s): vibration grows with speed, these ratios do not, which
    helps a run driven faster than any training run of its class.
    """
    X = np.asarray(X, dtype=np.float64)
    channels = list(channels)
    n, C, T = X.shape
    if C != len(channels):
        raise ValueError(f"features: X has {C} channels, got {len(channels)} names")
    X = np.where(np.isfinite(X), X, np.nanmean(X, axis=2, keepdims=True))
    X = np.nan_to_num(X)
    cols: dict[str, np.ndarray] = {}  # insertion order is the feature order
    c, std, dabs = _channel_stats(X, channels, rate_hz, bands_hz, cols)
    if correlations and C > 1:
        z = c / np.where(std > 1e-9, std, np.inf)[..., None]
        R = np.einsum("nit,njt->nij", z, z) / T
        for a in range(C):
            for b in range(a + 1, C):
                cols[f"corr__{channels[a]}__{channels[b]}"] = R[:, a, b]
    _side_physics(X, {ch: j for j, ch in enumerate(channels)}, std, dabs, track_m, cols)
    names = list(cols)
    F = np.stack([cols[k] for k in names], axis=1)
    return np.nan_to_num(F, nan=0.0, posinf=0.0, neginf=0.0), names


class SideChannelFeatures(TransformerMixin, BaseEstimator):
    """Stateless sklearn transformer of :func:`side_channel_features` (safe inside CV).

    Parameters
    ----------
    channel_names : names of the input channels for a plain (n, C, T) array (a ``Windows``
        input brings its own).
    rate_hz : float, sample rate. track_m : float, wheel track B (m).
    correlations : bool, include channel-pair correlations.
    """

    def __init__(self, channel_names: Sequence[str] | None = None, rate_hz: float = 100.0,
                 track_m: float = HUSKY_TRACK_M, correlations: bool = True):
        self.channel_names = channel_names
        self.rate_hz = rate_hz
        self.track_m = track_m
        self.correlations = correlations

    def _arr(self, X):
        names = getattr(X, "channels", None)
        if names is not None:
            return np.asarray(X.X, dtype=np.float64), list(names)
        if self.channel_names is None:
            raise ValueError("SideChannelFeatures: X is a plain array; give channel_names")
        return np.asarray(X, dtype=np.float64), list(self.channel_names)

    def fit(self, X, y=None):
        arr, names = self._arr(X)
        if arr.ndim != 3 or arr.shape[1] != len(names):
            raise ValueError(f"SideChannelFeatures: X must be (n, {len(names)}, T), got {arr.shape}")
        _, fn = side_channel_features(arr[:1], names, self.rate_hz, self.track_m, correlations=self.correlations)
        self.channel_names_ = names
        self.feature_names_out_ = np.asarray(fn, dtype=object)
        return self

    def transform(self, X) -> np.ndarray:
        check_is_fitted(self, "feature_names_out_")
        arr, names = self._arr(X)
        if names != self.channel_names_:
            raise ValueError(f"SideChannelFeatures: expected channels {self.channel_names_}, got {names}")
        F, _ = side_channel_features(arr, names, self.rate_hz, self.track_m, correlations=self.correlations)
        return F

    def get_feature_names_out(self, input_features=None) -> np.ndarray:
        check_is_fitted(self, "feature_names_out_")
        return np.asarray(self.feature_names_out_, dtype=object)


def _channel_stats(X: np.ndarray, channels: list[str], rate_hz: float, bands_hz, cols: dict):
    """Per channel statistics, band powers and centroid into ``cols``; returns x - mean, std, mad_diff."""
    T = X.shape[2]
    mean = X.mean(axis=2)
    c = X - mean[..., None]
    m2 = (c * c).mean(axis=2)
    std = np.sqrt(m2)
    safe = np.where(m2 > 1e-20, m2, 1.0)
    skew = np.where(m2 > 1e-20, (c ** 3).mean(axis=2) / safe ** 1.5, 0.0)
    kurt = np.where(m2 > 1e-20, (c ** 4).mean(axis=2) / safe ** 2 - 3.0, 0.0)
    p10, p50, p90 = np.percentile(X, [10, 50, 90], axis=2)
    dabs = np.abs(np.diff(X, axis=2)).mean(axis=2)
    f, P = welch(X, fs=rate_hz, nperseg=min(64, T), detrend="constant", axis=2)
    dfreq = f[1] - f[0]
    tot = P.sum(axis=2)
    centroid = np.where(tot > 0, (P * f).sum(axis=2) / np.where(tot > 0, tot, 1.0), 0.0)
    for j, ch in enumerate(channels):
        for nm, v in (("mean", mean), ("std", std), ("min", X.min(axis=2)), ("max", X.max(axis=2)),
                      ("p10", p10), ("p50", p50), ("p90", p90), ("skew", skew), ("kurtosis", kurt),
                      ("mad_diff", dabs), ("centroid_hz", centroid)):
            cols[f"{ch}__{nm}"] = v[:, j]
        for k, (lo, hi) in enumerate(bands_hz):
            last = k == len(bands_hz) - 1
            sel = (f >= lo) & ((f <= hi) if last else (f < hi))
            if sel.any():
                cols[f"{ch}__bp_{lo:g}_{hi:g}hz"] = np.log10(P[:, j, sel].sum(axis=1) * dfreq + 1e-12)
    return c, std, dabs


def _side_physics(X: np.ndarray, pos: dict[str, int], std, dabs, track_m: float, cols: dict) -> None:
    """Left-right current and speed, the skid indicator, roughness invariants, current per speed."""
    has_i = {"current_left", "current_right"} <= pos.keys()
    has_v = {"speed_left_mps", "speed_right_mps"} <= pos.keys()
    if has_i:
        iL, iR = X[:, pos["current_left"]], X[:, pos["current_right"]]
        cols["current_lr__diff_mean"] = (iL - iR).mean(axis=1)
        cols["current_lr__diff_std"] = (iL - iR).std(axis=1)
        cols["current_lr__sum_mean"] = (iL + iR).mean(axis=1)
        cols["current_lr__sum_std"] = (iL + iR).std(axis=1)
    if not has_v:
        return
    vL, vR = X[:, pos["speed_left_mps"]], X[:, pos["speed_right_mps"]]
    v = 0.5 * (vL + vR)
    cols["speed__forward_mean"] = v.mean(axis=1)
    cols["speed_lr__diff_mean"] = (vR - vL).mean(axis=1)
    cols["speed_lr__diff_std"] = (vR - vL).std(axis=1)
    if "imu_wz" in pos:
        wz = X[:, pos["imu_wz"]]
        wkin = (vR - vL) / track_m
        res = wz - wkin
        cols["skid__yaw_residual_mean"] = res.mean(axis=1)
        cols["skid__yaw_residual_std"] = res.std(axis=1)
        cols["skid__yaw_residual_abs"] = np.abs(res).mean(axis=1)
        cols["skid__yaw_ratio"] = np.abs(wz).mean(axis=1) / np.maximum(np.abs(wkin).mean(axis=1), MIN_SPEED_MPS)
    # roughness invariants (as on the reference robot, features.sets): the vibration a surface
    # profile excites grows with speed, so the spread per speed and per speed^2 describes the
    # surface rather than the manoeuvre (speed floored at 0.2 m/s; log10 for scale)
    v_floor = np.maximum(np.abs(v.mean(axis=1)), ROUGHNESS_MIN_SPEED_MPS)
    for ch in ROUGHNESS_CHANNELS:
        if ch not in pos:
            continue
        s_ch, d_ch = std[:, pos[ch]], dabs[:, pos[ch]]  # the per-channel std and mad_diff above
        cols[f"{ch}__log_std_per_speed2"] = np.log10(s_ch / v_floor ** 2 + 1e-9)
        cols[f"{ch}__log_std_per_speed"] = np.log10(s_ch / v_floor + 1e-9)
        cols[f"{ch}__log_mad_diff_per_speed"] = np.log10(d_ch / v_floor + 1e-9)
    if has_i:
        cols["current_total__log_abs_per_speed"] = np.log10(np.abs(iL + iR).mean(axis=1) / v_floor + 1e-6)
        vm = np.maximum(np.abs(v.mean(axis=1)), MIN_SPEED_MPS)
        cols["current_left__per_speed"] = iL.mean(axis=1) / np.maximum(np.abs(vL.mean(axis=1)), MIN_SPEED_MPS)
        cols["current_right__per_speed"] = iR.mean(axis=1) / np.maximum(np.abs(vR.mean(axis=1)), MIN_SPEED_MPS)
        cols["current_total__per_speed"] = (iL + iR).mean(axis=1) / vm
        cols["power_left__mean"] = (iL * vL).mean(axis=1)
        cols["power_right__mean"] = (iR * vR).mean(axis=1)
