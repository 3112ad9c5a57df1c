"""Where every window feature lives: names, buffer layout and what each column needs (design §8).

:func:`terrainml.features.sets.compute_features` computes every statistic as one whole-array
numpy operation over all windows and channels at once, written into one flat buffer whose column
layout (names, positions, Welch segments, percentile indices) depends only on the channel names
and the window length: :class:`FeatureLayout`, built once per channel list and window length
(:func:`feature_layout`, cached). The Welch spectrum is ``scipy.signal.welch``'s computation
(scipy >= 1.12 runs it through ``ShortTimeFFT``) written out with scipy's window and density
scaling: constant-detrended Hann segments, |DFT|^2, one-sided doubling, mean over segments. The
128-point real DFT is one matrix product (with the window folded in), faster than an FFT call for
the few segments of one window. Percentiles are numpy's ``linear`` method (the same index and
interpolation formulas) read from the sorted window.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Sequence

import numpy as np
from scipy.signal import ShortTimeFFT, get_window

__all__ = ["STATS", "BANDS_HZ", "SPECTRAL", "PHYSICS", "AGGREGATES", "PERCENTILES", "WELCH_NPERSEG",
           "FeatureLayout", "feature_layout", "feature_names", "columns_needed", "sense_source",
           "is_current_channel", "is_spectral_channel", "as_intp"]

STATS = ("mean", "std", "rms", "min", "max", "p10", "p50", "p90", "skew", "kurtosis")
BANDS_HZ = ((0.0, 5.0), (5.0, 15.0), (15.0, 30.0), (30.0, 50.0))
SPECTRAL = tuple(f"bp_{lo:g}_{hi:g}hz" for lo, hi in BANDS_HZ) + ("centroid_hz",)
PHYSICS = ("per_speed", "traction_effort", "slip_slope")
AGGREGATES = ("mean", "max", "spread")
PERCENTILES = (10.0, 50.0, 90.0)
WELCH_NPERSEG = 128


def is_current_channel(c: str) -> bool:
    return c.startswith("current_")


def is_spectral_channel(c: str) -> bool:
    return c.startswith("current_") or c == "imu_az"


def sense_source(channels: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Traction-sense pairing by name (``slip_i`` follows ``current_i``).

    Returns src (C,): position of the current whose sign each channel takes; flippable (C,)
    bool: whether it takes one; cur: positions of the current channels.
    """
    pos = {c: k for k, c in enumerate(channels)}
    src = np.arange(len(channels), dtype=np.intp)
    flippable = np.zeros(len(channels), dtype=bool)
    cur = [pos[c] for c in channels if is_current_channel(c)]
    for k in cur:
        flippable[k] = True
        s = f"slip_{channels[k][len('current_'):]}"
        if s in pos:
            src[pos[s]] = k
            flippable[pos[s]] = True
    return src, flippable, as_intp(cur)


def as_intp(v) -> np.ndarray:
    return np.asarray(v, dtype=np.intp).reshape(-1)


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
class FeatureLayout:
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
    sense: tuple  # sense_source
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
def feature_layout(channels: tuple[str, ...], T: int, rate_hz: float) -> FeatureLayout:
    """The feature layout of windows of ``channels`` (T samples at ``rate_hz``), worked out once."""
    C = len(channels)
    if len(set(channels)) != C or T < 1:
        raise ValueError(f"features: duplicate channel names in {list(channels)}" if len(set(channels)) != C
                         else f"features: windows need at least one sample, got T={T}")
    pos = {c: k for k, c in enumerate(channels)}
    spec_ch = [c for c in channels if is_spectral_channel(c)]
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
    return FeatureLayout(
        channels=channels, T=T, names=tuple(names), order=order,
        needs=tuple(needs.get(p, frozenset()) for p in range(n_flat)), n_flat=n_flat,
        sense=sense_source(channels),
        sort_idx=as_intp(np.concatenate(([0, T - 1], lo, hi, base))), pct_coef=np.asarray(coef, np.float64),
        spec_pos=as_intp([pos[c] for c in spec_ch]), spec_all=slice(0, len(spec_ch)), seg_idx=seg_idx,
        dft=dft, band_matrix=M,
        df_hz=df_hz, vx=pos.get("vx", -1), vy=pos.get("vy", -1), r=pos.get("r", -1),
        rough_pos=as_intp([pos[c] for c in rough]), az_spec=spos.get("imu_az", -1),
        ctx_yaw=at.get("body__abs_yaw_rate_mean", -1),
        ctx_rough=at.get(f"{rough[0]}__std_per_speed2", -1) if rough else -1,
        ctx_cpm=at.get("imu_az__centroid_per_m", -1),
        cur_pos=as_intp([pos[c] for _, c in cur_w]), cur_spec=as_intp([spos[c] for _, c in cur_w]),
        cur_wheel=tuple(i for i, _ in cur_w), slope_cur=as_intp([j for j, _ in cur_slip]),
        slope_slip=as_intp([p for _, p in cur_slip]), slip_pos=as_intp([pos[c] for _, c in slip_w]),
        cur_agg_phys=as_intp(agg_phys), o_spec=o_spec, o_ctx=o_ctx, o_phys=o_phys,
        o_slipw=o_slipw, o_agg_slip=o_agg_slip, o_agg_cur=o_agg_cur)


def _wheel_channels(channels: tuple[str, ...]) -> tuple[list, list]:
    """(wheel number, channel) of the slip and of the current channels, sorted by wheel."""
    slip_w = sorted((int(c[5:]), c) for c in channels if c.startswith("slip_"))
    cur_w = sorted((int(c[8:]), c) for c in channels if is_current_channel(c))
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
        first = [c for c in channels if is_current_channel(c)][0]
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
    return list(feature_layout(tuple(channels), int(n_samples), float(rate_hz)).names)


@lru_cache(maxsize=256)
def columns_needed(lay: FeatureLayout, columns: bytes) -> tuple[frozenset, slice | np.ndarray]:
    """What the named columns ``columns`` (intp bytes) need: tokens, spectral channel indices."""
    need: set = set()
    for p in lay.order[np.frombuffer(columns, dtype=np.intp)]:
        need |= lay.needs[p]
    spec = sorted(k for tok, k in (t for t in need if isinstance(t, tuple)))
    if spec and spec == list(range(spec[0], spec[-1] + 1)):
        spec = slice(spec[0], spec[-1] + 1)  # basic indexing: a view, cheaper
    return frozenset(t for t in need if not isinstance(t, tuple)), spec if spec else as_intp(spec)
