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
is one whole-array numpy operation over all windows and channels at once, written into one
flat buffer whose column layout (names, positions, Welch segments, percentile indices) depends
only on the channel names and the window length and is built once (:func:`_layout`, cached).
The Welch spectrum is ``scipy.signal.welch``'s computation (scipy >= 1.12 runs it through
``ShortTimeFFT``) written out with scipy's window and density scaling: constant-detrended Hann
segments, |DFT|^2, one-sided doubling, mean over segments. The 128-point real DFT is one matrix
product (with the window folded in), faster than an FFT call for the few segments of one
window; it agrees with ``scipy.signal.welch`` to ~1e-14 relative (a test checks it).
Percentiles are numpy's ``linear`` method (the same index and interpolation formulas) read from
the sorted window; a window with a non-finite sample goes through ``np.percentile``/``min``/
``max`` so that NaN propagates exactly as there. Asked for a subset of the columns (the SVM's
selected features), only what those need is computed.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Sequence

import numpy as np
from scipy.signal import ShortTimeFFT, get_window
from sklearn.base import BaseEstimator, TransformerMixin
from sklearn.exceptions import NotFittedError
from sklearn.utils.validation import check_is_fitted

__all__ = ["FeatureSet", "FEATURE_SUBSETS", "compute_features", "feature_names"]

FEATURE_SUBSETS: tuple[str, ...] = ("kinematic", "currents", "imu", "all")
STATS = ("mean", "std", "rms", "min", "max", "p10", "p50", "p90", "skew", "kurtosis")
BANDS_HZ = ((0.0, 5.0), (5.0, 15.0), (15.0, 30.0), (30.0, 50.0))
SPECTRAL = tuple(f"bp_{lo:g}_{hi:g}hz" for lo, hi in BANDS_HZ) + ("centroid_hz",)
PHYSICS = ("per_speed", "traction_effort", "slip_slope")
AGGREGATES = ("mean", "max", "spread")
PERCENTILES = (10.0, 50.0, 90.0)
WELCH_NPERSEG = 128
MIN_SPEED_MPS = 0.05
ROUGHNESS_MIN_SPEED_MPS = 0.2
SLOPE_RIDGE = 1e-6

_add = np.add.reduce
_max = np.maximum.reduce
_min = np.minimum.reduce


def _is_current(c: str) -> bool:
    return c.startswith("current_")


def _is_spectral(c: str) -> bool:
    return c.startswith("current_") or c == "imu_az"


def _sense_source(channels: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Traction-sense pairing by name (``slip_i`` follows ``current_i``).

    Returns src (C,): position of the current whose sign each channel takes; flippable (C,)
    bool: whether it takes one; cur: positions of the current channels.
    """
    pos = {c: k for k, c in enumerate(channels)}
    src = np.arange(len(channels), dtype=np.intp)
    flippable = np.zeros(len(channels), dtype=bool)
    cur = [pos[c] for c in channels if _is_current(c)]
    for k in cur:
        flippable[k] = True
        s = f"slip_{channels[k][len('current_'):]}"
        if s in pos:
            src[pos[s]] = k
            flippable[pos[s]] = True
    return src, flippable, _ip(cur)


def _ip(v) -> np.ndarray:
    return np.asarray(v, dtype=np.intp).reshape(-1)


def _sense_flips(X: np.ndarray, mean: np.ndarray, sense: tuple, finite: bool) -> np.ndarray | None:
    """(n, C) bool: the channels of each window whose sign the traction sense changes (None: none).

    X : (n, C, T); mean : (n, C) time means of X; sense : :func:`_sense_source`;
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
    flip = _sense_flips(X, mean, _sense_source(tuple(channels)), bool(np.isfinite(mean).all()))
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


def _welch_parts(T: int, rate_hz: float):
    """The pieces of ``scipy.signal.welch(x, fs, nperseg=min(128, T))`` (Hann, 50 % overlap,
    constant detrend, density scaling, one-sided, mean over segments) for windows of T samples.

    Returns
    -------
    seg_idx : (n_seg, nperseg) sample indices of the segments (scipy's: p0 = 0,
        p1 = (T - noverlap) // hop).
    dft : (nperseg, 2 n_freq) the real DFT with scipy's scaled window folded in:
        ``seg @ dft`` = [Re, Im] of ``rfft(seg * win)``, ``win`` = ``ShortTimeFFT(...,
        scale_to="psd").win`` (|.|^2 is then the density of that segment).
    f : (n_freq,) frequencies in Hz.
    bands : (n_seg * 2 n_freq, 6) maps the squared [Re, Im] of every segment to the
        segment-mean one-sided density summed over each band (4 columns), weighted by f
        (the centroid's numerator) and in total (one-sided doubling and 1/n_seg folded in).
    """
    nperseg = min(WELCH_NPERSEG, T)
    noverlap = nperseg // 2
    hop = nperseg - noverlap
    sft = ShortTimeFFT(get_window("hann", nperseg), hop, rate_hz, fft_mode="onesided",
                       mfft=nperseg, scale_to="psd", phase_shift=None)
    f = np.asarray(sft.f, dtype=np.float64)
    win = np.asarray(sft.win, dtype=np.float64)
    n_seg = (T - noverlap) // hop
    seg_idx = np.arange(n_seg)[:, None] * hop + np.arange(nperseg)[None, :]
    # exact integer phase k t mod N keeps the cos/sin arguments in [0, 2 pi)
    phase = 2.0 * np.pi * (np.outer(np.arange(nperseg), np.arange(f.size)) % nperseg) / nperseg
    dft = np.concatenate((win[:, None] * np.cos(phase), win[:, None] * np.sin(phase)), axis=1)
    double = np.ones(f.size)  # one-sided: all but DC (and Nyquist for an even nfft) doubled
    double[1:-1 if nperseg % 2 == 0 else None] = 2.0
    cols = []
    for k, (lo, hi) in enumerate(BANDS_HZ):
        last = k == len(BANDS_HZ) - 1
        cols.append(((f >= lo) & ((f <= hi) if last else (f < hi))).astype(np.float64))
    cols += [f, np.ones_like(f)]
    M = np.stack(cols, axis=1) * (double / n_seg)[:, None]
    return seg_idx, np.ascontiguousarray(dft), f, np.tile(np.concatenate((M, M)), (n_seg, 1))


# what each kind of column needs computed (see _needs)
_STAT_NEEDS = {"mean": (), "std": (), "rms": ("rms",), "min": ("sort",), "max": ("sort",),
               "p10": ("sort",), "p50": ("sort",), "p90": ("sort",), "skew": ("m34",),
               "kurtosis": ("m34",)}
_PHYS_NEEDS = {"per_speed": ("phys", "speed"), "traction_effort": ("phys",), "slip_slope": ("slope",)}


@dataclass(frozen=True, eq=False)
class _Layout:
    """Where every feature of one channel list and window length lives (built once, cached).

    The features are computed into a flat buffer of blocks: statistics (C, 10), spectra
    (S, 5), context, physics (wheels, 3), slip across wheels (2), aggregates over wheels
    (keys, 3); ``order`` maps the named columns (``names``, the public column order) to buffer
    positions and ``needs[p]`` says what buffer position p needs computed.
    """

    channels: tuple[str, ...]
    T: int
    names: tuple[str, ...]
    order: np.ndarray
    needs: tuple[frozenset, ...]
    n_flat: int
    sense: tuple  # _sense_source
    # order statistics on the sorted window: [min, max, lo x3, hi x3, base x3] and weights
    sort_idx: np.ndarray
    pct_coef: np.ndarray
    # spectra
    spec_pos: np.ndarray
    spec_all: slice  # all spectral channels
    seg_idx: np.ndarray
    dft: np.ndarray
    band_matrix: np.ndarray
    df_hz: float
    # context (body speed, yaw rate, roughness invariants): channel positions, context columns
    vx: int
    vy: int
    r: int
    rough_pos: np.ndarray
    az_spec: int
    ctx_yaw: int
    ctx_rough: int
    ctx_cpm: int
    # physics and aggregates, wheels in index order
    cur_pos: np.ndarray
    cur_spec: np.ndarray
    cur_wheel: tuple[int, ...]  # wheel numbers of the currents
    slope_cur: np.ndarray  # index into cur_pos of the wheels with a slip channel
    slope_slip: np.ndarray  # their slip channel positions
    slip_pos: np.ndarray
    cur_agg_phys: np.ndarray  # physics keys aggregated over wheels (indices into PHYSICS)
    # flat offsets
    o_spec: int
    o_ctx: int
    o_phys: int
    o_slipw: int
    o_agg_slip: int
    o_agg_cur: int


@lru_cache(maxsize=128)
def _layout(channels: tuple[str, ...], T: int, rate_hz: float) -> _Layout:
    """The feature layout of windows of ``channels`` (T samples at ``rate_hz``), worked out once."""
    C = len(channels)
    if len(set(channels)) != C or T < 1:
        raise ValueError(f"features: duplicate channel names in {list(channels)}" if len(set(channels)) != C
                         else f"features: windows need at least one sample, got T={T}")
    pos = {c: k for k, c in enumerate(channels)}
    spec_ch = [c for c in channels if _is_spectral(c)]
    spos = {c: k for k, c in enumerate(spec_ch)}
    slip_w, cur_w = _wheel_channels(channels)
    slips = dict(slip_w)
    has_speed = "vx" in pos and "vy" in pos
    flat: dict[str, int] = {}
    needs: dict[int, frozenset] = {}

    def put(name: str, at: int, need=()) -> None:
        flat[name] = at
        needs[at] = frozenset(need)

    spec_need = {c: (("spec", k),) for c, k in spos.items()}
    for ci, c in enumerate(channels):
        for j, k in enumerate(STATS):
            put(f"{c}__{k}", ci * len(STATS) + j, _STAT_NEEDS[k])
    o_spec = C * len(STATS)
    for si, c in enumerate(spec_ch):
        for j, k in enumerate(SPECTRAL):
            put(f"{c}__{k}", o_spec + si * len(SPECTRAL) + j, spec_need[c])
    o_ctx = o_spec + len(spec_ch) * len(SPECTRAL)
    ctx, rough = _context_columns(pos, spos, spec_need, has_speed)
    ctx_names = [nm for nm, _ in ctx]
    for k, (nm, need) in enumerate(ctx):
        put(nm, o_ctx + k, need)
    o_phys = o_ctx + len(ctx)
    phys_keys = []  # per wheel (index order): physics keys present
    for j, (i, c) in enumerate(cur_w):
        keys = ([0] if has_speed else []) + [1] + ([2] if i in slips else [])
        phys_keys.append(keys)
        for k in keys:
            put(f"{c}__{PHYSICS[k]}", o_phys + j * len(PHYSICS) + k, _PHYS_NEEDS[PHYSICS[k]])
    o_slipw = o_phys + len(cur_w) * len(PHYSICS)
    if slip_w:
        put("slip_wheels__mean", o_slipw, ("slipw_mean",))
        put("slip_wheels__spread", o_slipw + 1, ("slipw_spread",))
    o_agg_slip = o_slipw + (2 if slip_w else 0)
    slip_keys = list(STATS) if slip_w else []
    for j, k in enumerate(slip_keys):
        for a, agg in enumerate(AGGREGATES):
            put(f"slip_wheels__{k}__{agg}", o_agg_slip + j * len(AGGREGATES) + a,
                ("agg_slip",) + _STAT_NEEDS[k])
    o_agg_cur = o_agg_slip + len(slip_keys) * len(AGGREGATES)
    agg_phys, cur_keys = _current_aggregate_keys(channels, cur_w, phys_keys, spec_need)
    for j, (k, need) in enumerate(cur_keys):
        for a, agg in enumerate(AGGREGATES):
            put(f"current_wheels__{k}__{agg}", o_agg_cur + j * len(AGGREGATES) + a, ("agg_cur",) + need)
    n_flat = o_agg_cur + len(cur_keys) * len(AGGREGATES)

    names = _public_names(channels, spos, ctx_names, cur_w, phys_keys, slip_w, slip_keys, cur_keys)
    order = np.asarray([flat[nm] for nm in names], dtype=np.intp)
    lo, hi, base, coef = _percentile_plan(T)

    seg_idx, dft, M, df_hz = _spectral_plan(bool(spec_ch), T, rate_hz)
    cur_slip = [(j, pos[slips[i]]) for j, (i, _) in enumerate(cur_w) if i in slips]
    at = {nm: k for k, nm in enumerate(ctx_names)}
    return _Layout(
        channels=channels, T=T, names=tuple(names), order=order,
        needs=tuple(needs.get(p, frozenset()) for p in range(n_flat)), n_flat=n_flat,
        sense=_sense_source(channels),
        sort_idx=_ip(np.concatenate(([0, T - 1], lo, hi, base))), pct_coef=np.asarray(coef, np.float64),
        spec_pos=_ip([pos[c] for c in spec_ch]), spec_all=slice(0, len(spec_ch)), seg_idx=seg_idx,
        dft=dft, band_matrix=M,
        df_hz=df_hz, vx=pos.get("vx", -1), vy=pos.get("vy", -1), r=pos.get("r", -1),
        rough_pos=_ip([pos[c] for c in rough]), az_spec=spos.get("imu_az", -1),
        ctx_yaw=at.get("body__abs_yaw_rate_mean", -1),
        ctx_rough=at.get(f"{rough[0]}__std_per_speed2", -1) if rough else -1,
        ctx_cpm=at.get("imu_az__centroid_per_m", -1),
        cur_pos=_ip([pos[c] for _, c in cur_w]), cur_spec=_ip([spos[c] for _, c in cur_w]),
        cur_wheel=tuple(i for i, _ in cur_w), slope_cur=_ip([j for j, _ in cur_slip]),
        slope_slip=_ip([p for _, p in cur_slip]), slip_pos=_ip([pos[c] for _, c in slip_w]),
        cur_agg_phys=_ip(agg_phys), o_spec=o_spec, o_ctx=o_ctx, o_phys=o_phys,
        o_slipw=o_slipw, o_agg_slip=o_agg_slip, o_agg_cur=o_agg_cur)


def _wheel_channels(channels: tuple[str, ...]) -> tuple[list, list]:
    """(wheel number, channel) of the slip and of the current channels, sorted by wheel."""
    slip_w = sorted((int(c[5:]), c) for c in channels if c.startswith("slip_"))
    cur_w = sorted((int(c[8:]), c) for c in channels if _is_current(c))
    for fam, ws in (("slip", slip_w), ("current", cur_w)):
        if len({i for i, _ in ws}) != len(ws):
            raise ValueError(f"features: two {fam} channels share a wheel number in {list(channels)}")
    return slip_w, cur_w


def _context_columns(pos: dict, spos: dict, spec_need: dict, has_speed: bool) -> tuple[list, list]:
    """Context columns (name, needs) and the roughness channels: speed, yaw rate, roughness, cpm."""
    ctx: list[tuple[str, tuple]] = []
    rough: list[str] = []
    if has_speed:
        ctx.append(("body__speed_mean", ("speed",)))
        if "r" in pos:
            ctx.append(("body__abs_yaw_rate_mean", ("yaw",)))
        rough = [c for c in ("imu_az", "imu_ax") if c in pos]
        ctx += [(f"{c}__std_per_speed2", ("speed", "rough")) for c in rough]
        if "imu_az" in spos:
            ctx.append(("imu_az__centroid_per_m", ("speed", "cpm") + spec_need["imu_az"]))
    return ctx, rough


def _current_aggregate_keys(channels, cur_w: list, phys_keys: list, spec_need: dict) -> tuple[list, list]:
    """Physics keys aggregated over wheels and the (key, needs) of every current aggregate."""
    agg_phys: list[int] = []
    if cur_w:
        # keys of the first current channel (channel order), as in a per-wheel dict
        first = [c for c in channels if _is_current(c)][0]
        agg_phys = phys_keys[[c for _, c in cur_w].index(first)]
        for (i, c), keys in zip(cur_w, phys_keys):
            if not set(agg_phys) <= set(keys):
                raise ValueError(f"features: wheel {i} has no slip channel but {first}'s wheel has "
                                 "one; give every wheel with a current a slip channel, or none")
    all_cur_spec = tuple(n for _, c in cur_w for n in spec_need[c])
    cur_keys = ([(k, _STAT_NEEDS[k]) for k in STATS] if cur_w else []) \
        + ([(k, all_cur_spec) for k in SPECTRAL] if cur_w else []) \
        + [(PHYSICS[k], _PHYS_NEEDS[PHYSICS[k]]) for k in agg_phys]
    return agg_phys, cur_keys


def _public_names(channels, spos, ctx_names, cur_w, phys_keys, slip_w, slip_keys, cur_keys) -> list[str]:
    """Public column order (per channel: stats then spectra; context; physics; slip; aggregates)."""
    names = []
    for c in channels:
        names += [f"{c}__{k}" for k in STATS] + ([f"{c}__{k}" for k in SPECTRAL] if c in spos else [])
    names += ctx_names
    for (i, c), keys in zip(cur_w, phys_keys):
        names += [f"{c}__{PHYSICS[k]}" for k in keys]
    if slip_w:
        names += ["slip_wheels__mean", "slip_wheels__spread"]
    names += [f"slip_wheels__{k}__{agg}" for k in slip_keys for agg in AGGREGATES]
    names += [f"current_wheels__{k}__{agg}" for k, _ in cur_keys for agg in AGGREGATES]
    return names


def _spectral_plan(any_spectral: bool, T: int, rate_hz: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Welch segment indices, DFT matrix, band matrix and bin width (Hz); empty without spectra."""
    if not any_spectral:
        return np.zeros((0, 0), np.intp), np.zeros((0, 0)), np.zeros((0, 6)), 1.0
    seg_idx, dft, f, M = _welch_parts(T, float(rate_hz))
    return seg_idx, dft, M, float(f[1] - f[0]) if f.size > 1 else 1.0


def _percentile_plan(T: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Percentiles as numpy's "linear" method: virtual index (T - 1) q, interpolation weight t.

    Returns the lower and upper sorted indices, the base index and the weight of numpy's _lerp
    (``b - (b - a)(1 - t)`` when t >= 0.5), per percentile of :data:`PERCENTILES`.
    """
    q = np.true_divide(np.asarray(PERCENTILES), 100)
    vi = (T - 1) * q
    lo = np.floor(vi).astype(np.intp)
    hi = np.minimum(lo + 1, T - 1)
    top = vi >= T - 1
    lo[top], hi[top] = T - 1, T - 1
    t = vi - lo
    base = np.where(t >= 0.5, hi, lo)
    coef = np.where(t >= 0.5, -(1 - t), t)
    return lo, hi, base, coef


def feature_names(channels: Sequence[str], n_samples: int = 200, rate_hz: float = 100.0) -> list[str]:
    """Names of the columns :func:`compute_features` returns for these channels, in order."""
    return list(_layout(tuple(channels), int(n_samples), float(rate_hz)).names)


@lru_cache(maxsize=256)
def _needs(lay: _Layout, columns: bytes) -> tuple[frozenset, slice | np.ndarray]:
    """What the named columns ``columns`` (intp bytes) need: tokens, spectral channel indices."""
    need: set = set()
    for p in lay.order[np.frombuffer(columns, dtype=np.intp)]:
        need |= lay.needs[p]
    spec = sorted(k for tok, k in (t for t in need if isinstance(t, tuple)))
    if spec and spec == list(range(spec[0], spec[-1] + 1)):
        spec = slice(spec[0], spec[-1] + 1)  # basic indexing: a view, cheaper
    return frozenset(t for t in need if not isinstance(t, tuple)), spec if spec else _ip(spec)


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


def _flat_features(X: np.ndarray, lay: _Layout, torque_constant_nm_per_a: float,
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
        need, spec_k = _needs(lay, np.ascontiguousarray(columns, dtype=np.intp).tobytes())
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


def _stat_block(X, mean, lay: _Layout, has, finite: bool, out: np.ndarray):
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


def _spectral_block(X, lay: _Layout, spec_k, out: np.ndarray) -> np.ndarray:
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


def _context_block(X, lay: _Layout, has, st, sp, out: np.ndarray):
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


def _physics_block(lay: _Layout, has, mean, c, m2, speed, out: np.ndarray, torque_constant_nm_per_a: float,
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


def _aggregate_block(X, lay: _Layout, has, st, sp, ph, out: np.ndarray) -> None:
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
    lay = _layout(channels, int(X.shape[2]), float(rate_hz))
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
        lay = _layout(tuple(names), int(arr.shape[2]), float(self.rate_hz))
        cols = self._keep if columns is None else self._keep[columns]
        flat = _flat_features(arr, lay, float(self.torque_constant_nm_per_a), float(self.wheel_radius_m),
                              _loads_key(self.wheel_loads_n), None if self.subset == "all" and columns is None
                              else cols)
        return flat.take(lay.order[cols], axis=1)

    def get_feature_names_out(self, input_features=None) -> np.ndarray:
        check_is_fitted(self, "feature_names_out_")
        return np.asarray(self.feature_names_out_, dtype=object)
