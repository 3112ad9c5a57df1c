"""Resampling asynchronous samples onto the uniform base-rate grid (design §5), vectorised.

Rules
-----
* ``linear``: linear interpolation between the bracketing samples (continuous signals);
* ``previous``: the latest sample at or before the tick (encoders, labels, confidence);
* ``angle``: unwrap, interpolate linearly, wrap to (-pi, pi];
* a tick is **invalid** where the bracketing interval (linear) or the age of the held sample
  (previous) exceeds ``max_gap_s``, before the first sample, after the last, or where a used
  sample is not finite. Invalid ticks hold NaN.

The gap threshold used by ingest is ``2 * max(base period, median source period)``: two base
periods as design §5 says for sensors at or above the base rate; for slower sensors (a 10 Hz wheel
odometry) their own spacing is not a gap (documented departure).
"""

from __future__ import annotations

import math

import numpy as np

_EPS = 1e-9


def clean_times(t: np.ndarray) -> tuple[np.ndarray, int, int]:
    """Order that sorts ``t`` and drops duplicate stamps; returns (index, n_out_of_order, n_duplicates)."""
    t = np.asarray(t)
    out_of_order = int(np.count_nonzero(np.diff(t) < 0)) if len(t) > 1 else 0
    order = np.argsort(t, kind="stable")
    ts = t[order]
    keep = np.ones(len(ts), bool)
    if len(ts) > 1:
        keep[1:] = np.diff(ts) > 0
    return order[keep], out_of_order, int(np.count_nonzero(~keep))


def gap_threshold_s(t_src_s: np.ndarray, rate_hz: float, periods: float = 2.0) -> float:
    """``periods * max(base period, median source period)`` (s): the gap rule of design §5 (D2)."""
    base = 1.0 / rate_hz
    if len(t_src_s) < 2:
        return periods * base
    return periods * max(base, float(np.median(np.diff(t_src_s))))


def resample(t_src: np.ndarray, values: np.ndarray, grid: np.ndarray, *, method: str = "linear",
             max_gap_s: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
    """Resample ``values`` (n, k) sampled at sorted unique ``t_src`` (n,) onto ``grid`` (m,).

    Returns (out (m, k) with NaN where invalid, valid (m, k) bool).
    """
    t_src = np.asarray(t_src, float)
    v = np.asarray(values, float)
    squeeze = v.ndim == 1
    if squeeze:
        v = v[:, None]
    m, k = len(grid), v.shape[1]
    if len(t_src) == 0:
        out = np.full((m, k), np.nan)
        return (out[:, 0], np.zeros(m, bool)) if squeeze else (out, np.zeros((m, k), bool))
    if method == "angle":
        finite = np.isfinite(v)
        vu = np.where(finite, v, 0.0)
        vu = np.unwrap(vu, axis=0)
        vu[~finite] = np.nan
        out, valid = resample(t_src, vu, grid, method="linear", max_gap_s=max_gap_s)
        out = np.pi - np.mod(np.pi - out, 2.0 * np.pi)
        out[~valid] = np.nan
        return (out[:, 0], valid[:, 0]) if squeeze else (out, valid)
    n = len(t_src)
    idx = np.searchsorted(t_src, grid + _EPS, side="right")     # samples at or before the tick
    lo = np.clip(idx - 1, 0, n - 1)
    have_prev = idx >= 1
    finite = np.isfinite(v)
    if method == "previous":
        age = grid - t_src[lo]
        ok_t = have_prev & (age <= max_gap_s + _EPS)
        out = v[lo].copy()
        valid = ok_t[:, None] & finite[lo]
    elif method == "linear":
        hi = np.clip(idx, 0, n - 1)
        exact = have_prev & (np.abs(grid - t_src[lo]) <= _EPS)
        inside = have_prev & (idx < n)
        span = t_src[hi] - t_src[lo]
        ok_t = exact | (inside & (span <= max_gap_s + _EPS))
        with np.errstate(invalid="ignore", divide="ignore"):
            w = np.where(exact | (span <= 0), 0.0, (grid - t_src[lo]) / np.where(span > 0, span, 1.0))
        with np.errstate(invalid="ignore"):
            out = v[lo] + w[:, None] * (v[hi] - v[lo])
        out[exact] = v[lo[exact]]
        fin = finite[lo] & np.where(exact[:, None], True, finite[hi])
        valid = ok_t[:, None] & fin
    else:
        raise ValueError(f"unknown resample method {method!r}")
    out = np.where(valid, out, np.nan)
    return (out[:, 0], valid[:, 0]) if squeeze else (out, valid)


def at_tick(g: float, t_lo: float | None, v_lo: float, t_hi: float | None, v_hi: float, method: str,
            max_gap_s: float) -> tuple[float, bool]:
    """:func:`resample` at one tick ``g`` from its bracketing samples, in plain floats.

    ``t_lo``/``v_lo``: the last sample at or before ``g + _EPS`` (None: there is none); ``t_hi``/``v_hi``:
    the first one after it (None: none yet). Same rules and the same floating-point operations as
    :func:`resample` (``angle``: the pair unwrapped as ``numpy.unwrap`` does it), so a tick served
    live (:class:`terrainml.io.ingest.ticks.TickProducer`) equals the tick of the vectorised table:
    one numpy call costs tens of microseconds on arrays this small, a tick has some 40 columns, and
    the live budget is a fraction of a 10 ms base period. Returns (value, NaN where invalid; valid).
    """
    if t_lo is None or v_lo != v_lo or math.isinf(v_lo):
        return math.nan, False
    if method == "previous":
        return (v_lo, True) if g - t_lo <= max_gap_s + _EPS else (math.nan, False)
    if abs(g - t_lo) <= _EPS:
        out = v_lo
    else:
        if t_hi is None or v_hi != v_hi or math.isinf(v_hi):
            return math.nan, False
        span = t_hi - t_lo
        if not span <= max_gap_s + _EPS:
            return math.nan, False
        if method == "angle":   # numpy.unwrap of the pair (period 2 pi, discontinuity pi)
            dd = v_hi - v_lo
            ddmod = (dd + math.pi) % (2.0 * math.pi) - math.pi
            if ddmod == -math.pi and dd > 0:
                ddmod = math.pi
            v_hi = v_hi + (0.0 if abs(dd) < math.pi else ddmod - dd)
        out = v_lo + ((g - t_lo) / span) * (v_hi - v_lo)
    if method == "angle":
        out = math.pi - (math.pi - out) % (2.0 * math.pi)
    return out, True
