"""Online refinement of the slip cap from the robot's own thrust-slip data (design §12; issue 20).

The class target s_T is the traction peak of the class's *nominal* soil; a terrain draw shifts
the true peak (sand: a draw at 0.392 against 0.421 nominal). The robot measures both axes of the
curve itself:

* **thrust** per wheel from the motor current, ``H = k_t i / R`` (N; the wheel's inertia term
  ``J d(omega)/dt / R`` is a few N against 100 N of thrust at the reference wheel and is dropped);
* **slip** per wheel: the shear-lagged regularised slip of the slip limiter
  (:class:`~terrainml.control.slip_limiter.SlipLimiter`), the slip the soil's shear stress
  follows (Janosi-Hanamoto in displacement form, design §6.2).

Estimator (per wheel, :class:`CapRefiner`):

1. **binned curve with forgetting.** Traction samples (thrust > 0, slip in ``[s_lo, s_hi]``,
   slip changing slowly: ``|ds/dt| <= max_slip_rate``, so the lagged slip is the one the thrust
   follows) go into bins of ``bin_width`` slip. Each bin holds a weight ``w_b`` and a weighted mean
   thrust ``m_b``; every bin forgets by ``exp(-dx / memory_m)`` per ``dx`` metres the wheel's
   surface travels (the terrain under the wheel changes with distance, not time; a wheel at
   a stall keeps its data).
2. **peak of thrust.** The argmax bin ``k*`` among the bins with ``w_b >= min_bin_weight``; a
   weighted quadratic ``m(s) = a s^2 + b s + c`` fitted over the bins within ``fit_halfwidth`` of
   ``k*``; its vertex ``s_H = -b / 2a`` when the fit is concave (``a < 0``), has data on both
   sides of the vertex and the vertex lies inside the fitted range. Otherwise no peak is
   confirmed (the curve still rises at the highest slip seen, or is flat within noise).
3. **thrust peak -> net traction peak.** The motor sees gross thrust H; the cap wanted is the
   peak of *net* traction H - R (design §10), which sits lower because the motion resistance
   grows with slip (slip-sinkage). The refiner subtracts the class's offset
   ``delta = s_H(nominal) - s_T(nominal)``, computed by the same quadratic fit on the class's
   nominal thrust curve (:func:`thrust_peak_offset`), so the fit's own bias on an asymmetric
   hump cancels too.
4. **band and probing.** The cap served is ``clip(s_H - delta, s_T - band, s_T + band)``. Until a
   peak is confirmed the refiner *probes*: it serves ``s_T + probe`` so that the wheel can visit
   slips past the nominal peak (otherwise a draw whose peak lies above nominal would never show
   its peak: the cap would hide it). The served cap moves at most ``max_cap_rate_per_m`` per metre
   of wheel travel, so a new estimate never steps the cap.

Failure modes (documented in docs/control.md):

* **not enough excitation**: cruise at low demand keeps the slip at the soil's cruise slip, far
  below the peak; no bin near the peak fills and the refiner serves the class target (or the
  probe). It needs starts, grades or a load that push the slip through the peak;
* **load changes**: thrust scales with the wheel load, which a grade (pitch transfer), a cart's
  tongue or a growing payload change; samples taken at different loads blend into one curve.
  The peak's *slip* barely moves with load, but a load step between the two sides of the peak
  tilts the curve and biases the vertex. Forgetting by distance bounds how long it lasts;
* **grade**: gravity does not enter the wheel's thrust-slip relation, but the pitch load transfer
  does (previous item), and on a grade at a stall all samples sit at one slip;
* **transients**: the shear lag's contact length is an assumption; a wrong length skews the
  slip of fast transients, which the slip-rate gate drops;
* **terrain changes** under a wheel mix two curves until the old one is forgotten (memory_m);
* **class-free fallback**: with no class there is no nominal curve to take the offset from;
  the safe cap is served unrefined.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["CapRefiner", "CapRefinerConfig", "local_quadratic_peak", "thrust_peak_offset"]


@dataclass(frozen=True)
class CapRefinerConfig:
    """Parameters of :class:`CapRefiner` (slips are unitless SAE slip, distances m).

    Parameters
    ----------
    band : largest departure of the served cap from the class target (*issue 20*: 0.1).
    probe : cap above the class target served until a peak is confirmed (*assumption*: 0.06,
        the spread of the draws' peaks around nominal at the simulator's ±15 % parameter spread).
    bin_width : slip bin width (0.02).
    s_lo, s_hi : slip range of the bins (0.02 .. 0.9).
    memory_m : m of wheel surface travel over which old samples fade by 1/e (*assumption*: 8 m).
    min_bin_weight : samples (forgetting-weighted) a bin needs to count (*assumption*: 5, 50 ms).
    fit_halfwidth : slip half-width of the quadratic fit around the argmax bin (0.08).
    max_slip_rate : 1/s, samples with a faster-changing slip are dropped (*assumption*: 2 /s).
    max_cap_rate_per_m : largest change of the served cap per metre of wheel travel (0.05).
    """

    band: float = 0.1
    probe: float = 0.06
    bin_width: float = 0.02
    s_lo: float = 0.02
    s_hi: float = 0.9
    memory_m: float = 8.0
    min_bin_weight: float = 5.0
    fit_halfwidth: float = 0.08
    max_slip_rate: float = 2.0
    max_cap_rate_per_m: float = 0.05

    def __post_init__(self) -> None:
        for name in ("band", "bin_width", "memory_m", "min_bin_weight", "fit_halfwidth",
                     "max_slip_rate", "max_cap_rate_per_m"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"CapRefinerConfig.{name} must be finite and > 0, got {v!r}")
        if not 0.0 <= self.probe <= self.band:
            raise ValueError(f"CapRefinerConfig.probe must be in [0, band], got {self.probe!r}")
        if not 0.0 <= self.s_lo < self.s_hi <= 1.0:
            raise ValueError("CapRefinerConfig: need 0 <= s_lo < s_hi <= 1")


def local_quadratic_peak(centres: np.ndarray, means: np.ndarray, weights: np.ndarray,
                         min_weight: float, halfwidth: float) -> float | None:
    """Vertex of a weighted quadratic fitted around the argmax of a binned curve.

    Parameters
    ----------
    centres : (B,) bin centres (slip).
    means : (B,) mean value per bin (thrust, N, or any unit).
    weights : (B,) weight per bin; bins below ``min_weight`` are ignored.
    min_weight : weight a bin needs.
    halfwidth : slip half-width of the fit around the argmax bin.

    Returns
    -------
    float, the slip of the vertex, or None when no peak is confirmed: fewer than 3 bins in the
    fit, a convex or flat fit, no bin on one side of the vertex, or a vertex outside the fit.
    """
    ok = weights >= min_weight
    if ok.sum() < 3:
        return None
    k = int(np.argmax(np.where(ok, means, -np.inf)))
    sel = ok & (np.abs(centres - centres[k]) <= halfwidth + 1e-12)
    if sel.sum() < 3:
        return None
    x, y, w = centres[sel], means[sel], weights[sel]
    a, b, _ = np.polyfit(x, y, 2, w=np.sqrt(w))
    if not a < 0.0:
        return None
    s = -b / (2.0 * a)
    if not (x.min() < s < x.max()) or not (np.any(x < s) and np.any(x > s)):
        return None
    return float(s)


def thrust_peak_offset(slip: np.ndarray, thrust: np.ndarray, net_peak_slip: float,
                       config: CapRefinerConfig | None = None) -> float:
    """``delta = s_H - s_T``: the refiner's thrust-peak estimate on a *nominal* curve minus that
    curve's net-traction peak ``net_peak_slip`` (the class target).

    ``slip`` (M,) and ``thrust`` (M,) sample the class's nominal gross-thrust curve at its static
    load (any unit); the same binning and fit as :class:`CapRefiner` is applied, so its bias on an
    asymmetric hump cancels. Returns 0.0 when the nominal curve shows no peak in range.
    """
    cfg = config or CapRefinerConfig()
    edges = np.arange(cfg.s_lo, cfg.s_hi + 1e-9, cfg.bin_width)
    centres = 0.5 * (edges[:-1] + edges[1:])
    s = np.asarray(slip, dtype=float)
    h = np.asarray(thrust, dtype=float)
    means = np.interp(centres, s, h)
    s_h = local_quadratic_peak(centres, means, np.ones_like(centres), 0.5, cfg.fit_halfwidth)
    return 0.0 if s_h is None else float(s_h - net_peak_slip)


class CapRefiner:
    """Per-wheel online refinement of the traction cap (module docstring).

    Parameters
    ----------
    n_wheels : number of wheels N.
    config : :class:`CapRefinerConfig`.

    Attributes
    ----------
    weights, means : (N, B) forgetting-weighted sample count and mean thrust (N) per slip bin.
    peak_thrust_slip : (N,) last confirmed thrust-peak slip per wheel (NaN: none yet).
    served : (N,) cap served at the last :meth:`cap` call (NaN before the first).
    """

    def __init__(self, n_wheels: int, config: CapRefinerConfig | None = None) -> None:
        self.n_wheels = int(n_wheels)
        self.config = config or CapRefinerConfig()
        cfg = self.config
        self.edges = np.arange(cfg.s_lo, cfg.s_hi + 1e-9, cfg.bin_width)
        self.centres = 0.5 * (self.edges[:-1] + self.edges[1:])
        nb = len(self.centres)
        self.weights = np.zeros((self.n_wheels, nb))
        self.means = np.zeros((self.n_wheels, nb))
        self.peak_thrust_slip = np.full(self.n_wheels, np.nan)
        self.served = np.full(self.n_wheels, np.nan)
        self._s_prev = np.full(self.n_wheels, np.nan)
        self._dist_since_cap = np.zeros(self.n_wheels)
        self._class_key: tuple | None = None

    def reset(self, wheels=None) -> None:
        """Forget every sample (all wheels, or an index): a new terrain class was served."""
        idx = slice(None) if wheels is None else wheels
        self.weights[idx] = 0.0
        self.means[idx] = 0.0
        self.peak_thrust_slip[idx] = np.nan

    def update(self, slip, thrust_n, surface_travel_m, dt_s: float) -> None:
        """Add one tick of samples.

        Parameters
        ----------
        slip : (N,) shear-lagged slip per wheel, signed in the driving direction (> 0 traction).
        thrust_n : (N,) gross thrust per wheel, N, signed like the slip (``k_t i / R`` times the
            driving direction).
        surface_travel_m : (N,) m the wheel's surface moved this tick (``|omega| R dt``): the
            forgetting clock.
        dt_s : s, tick length (for the slip-rate gate).
        """
        cfg = self.config
        s = np.asarray(slip, dtype=float)
        h = np.asarray(thrust_n, dtype=float)
        dx = np.nan_to_num(np.abs(np.asarray(surface_travel_m, dtype=float)))
        self.weights *= np.exp(-dx / cfg.memory_m)[:, None]
        self._dist_since_cap += dx
        rate = np.abs(s - self._s_prev) / dt_s if dt_s > 0 else np.full_like(s, np.inf)
        self._s_prev = s
        take = (np.isfinite(s) & np.isfinite(h) & (h > 0.0) & (s >= cfg.s_lo) & (s < cfg.s_hi)
                & np.isfinite(rate) & (rate <= cfg.max_slip_rate))
        for i in np.flatnonzero(take):
            b = int((s[i] - cfg.s_lo) // cfg.bin_width)
            if 0 <= b < self.weights.shape[1]:
                w = self.weights[i, b] + 1.0
                self.means[i, b] += (h[i] - self.means[i, b]) / w
                self.weights[i, b] = w

    def peak(self, wheel: int) -> float | None:
        """Confirmed thrust-peak slip of one wheel (None when not confirmed)."""
        cfg = self.config
        return local_quadratic_peak(self.centres, self.means[wheel], self.weights[wheel],
                                    cfg.min_bin_weight, cfg.fit_halfwidth)

    def cap(self, class_target, offset) -> np.ndarray:
        """Traction cap to serve per wheel.

        Parameters
        ----------
        class_target : (N,) or scalar, the class's traction target s_T (> 0).
        offset : (N,) or scalar, :func:`thrust_peak_offset` of that class (NaN: no nominal curve,
            e.g. the class-free safe cap: the target is served unrefined).

        Returns
        -------
        (N,) traction cap: ``clip(s_H - offset, s_T - band, s_T + band)`` where a peak is
        confirmed, ``s_T + probe`` where not, rate-limited per metre of wheel travel.
        """
        cfg = self.config
        n = self.n_wheels
        base = np.broadcast_to(np.asarray(class_target, dtype=float), (n,)).copy()
        off = np.broadcast_to(np.asarray(offset, dtype=float), (n,))
        key = tuple(np.round(base, 6))
        if self._class_key is not None and key != self._class_key:
            changed = np.abs(np.asarray(key) - np.asarray(self._class_key)) > 1e-9
            self.reset(np.flatnonzero(changed))     # another class: its curve is another curve
            self.served[changed] = np.nan
        self._class_key = key
        want = base.copy()
        for i in range(n):
            if not np.isfinite(off[i]) or not np.isfinite(base[i]):
                continue
            s_h = self.peak(i)
            self.peak_thrust_slip[i] = np.nan if s_h is None else s_h
            want[i] = base[i] + cfg.probe if s_h is None else s_h - off[i]
        want = np.clip(want, base - cfg.band, base + cfg.band)
        step = cfg.max_cap_rate_per_m * self._dist_since_cap
        prev = np.where(np.isfinite(self.served), self.served, want)
        out = np.where(np.isfinite(off), prev + np.clip(want - prev, -step, step), base)
        self._dist_since_cap[:] = 0.0
        self.served = out
        return out
