"""Online refinement of the slip cap from the robot's own thrust-slip data (design §12).

The class target s_T is the traction peak of the class's *nominal* soil; a terrain draw shifts
the true peak (sand: a draw at 0.392 against 0.421 nominal). The robot measures both axes of the
curve itself:

* **thrust** per wheel from the motor current, ``H = k_t i / R`` (N; the wheel's inertia term
  ``J d(omega)/dt / R`` is a few N against 100 N of thrust at the reference wheel and is dropped);
* **slip** per wheel: the shear-lagged regularised slip of the slip limiter
  (:class:`~terrainml.control.slip_limiter.SlipLimiter`), the slip the soil's shear stress
  follows (Janosi-Hanamoto in displacement form, design §6.2).

Estimator (per wheel, :class:`CapRefiner`): **a shift of the class's thrust-slip curve**, read where
the data are dense (the rise), not at the peak, where they are not.

Why not fit the peak itself: the thrust-slip hump of a sandy soil is flat (within about 1 % over
+-0.03 slip around its peak) and the limiter keeps the slip at the cap, so the samples that reach
the peak are a few transient ticks at a start; a local quadratic on them did not converge within
0.1 after 10 m of traction (tuning draws 5003, 5006, 5027). The *rise* of the curve, from the
free slip (no thrust below it, design §6.2) to the plateau, is steep and every start and every
cruise under load crosses it. In the terramechanics model of a class the draws' peaks move with
their free slip (dry sand: peak minus free slip 0.13-0.16 over the draws' +-15 % parameter
spread), so the horizontal shift of the rise against the class's nominal curve is the shift of
the peak.

1. **binned curve with forgetting.** Traction samples (thrust > 0, slip in ``[s_lo, s_hi]``,
   slip changing slowly: ``|ds/dt| <= max_slip_rate``, so the lagged slip is the one the thrust
   follows) go into bins of ``bin_width`` slip. Each bin holds a weight ``w_b``, a weighted mean
   thrust ``m_b`` and a weighted mean slip ``s_b`` (so a bin's slip is where its samples were,
   not its centre); every bin forgets by ``exp(-dx / memory_m)`` per ``dx`` metres the wheel's
   surface travels (the terrain under the wheel changes with distance, not time; a wheel at a
   stall keeps its data).
2. **crossings at the data's own levels.** With ``m_max`` the largest mean over the bins with
   ``w_b >= min_bin_weight`` (the plateau; confirmed only when a second such bin reaches
   ``plateau_level m_max``: the curve has flattened), every qualified bin with
   ``r_b = m_b / m_max`` in ``[level_lo, level_hi]`` and at least ``min_plateau_span`` of slip
   below the plateau bin is a crossing of the rise at level ``r_b``. A level is invariant to the
   thrust's scale (wheel load, the current-to-thrust constant, the soil's strength), so the
   current need not be calibrated. Why not one fixed level (half the plateau, the first version):
   with the mission limiter's build-up gain (``kp_build_mps`` 6) a start runs up the rise faster
   than the slip-rate gate admits; the slow samples are the cruise slip (dry sand under a cart:
   0.7-0.9 of the plateau) and the plateau, so half the plateau was never seen.
3. **shift -> cap.** The class's offsets ``delta(r) = s_R,nom(r) - s_T(nominal)`` are the crossings
   of the class's nominal gross-thrust curve at the levels ``r`` minus its net-traction peak
   (:func:`thrust_peak_offset`). Each rise bin estimates the draw's peak as ``s_b - delta(r_b)``
   (the class target moved by the bin's shift against the nominal curve); the estimate is their
   mean weighted by ``min(w_b, max_bin_weight)`` (the cruise bin, with thousands of samples, does
   not hide the others).
4. **band and probing.** The cap served is ``clip(estimate, s_T - band, s_T + band)``. Until an
   estimate is confirmed the refiner serves ``s_T + probe`` (default 0: the class target; the
   rise lies below the peak, so no probing past the cap is needed to see it). The served cap
   moves at most ``max_cap_rate_per_m`` per metre of wheel travel, so a new estimate never steps
   the cap.

Failure modes (documented in docs/control.md):

* **not enough excitation**: an estimate needs a slow sample on the rise and a flat top; cruise at
  low demand keeps the slip at the soil's cruise slip, at the foot of the rise, and the refiner
  serves the class target until a start, a grade or a load pushes the slip up the rise;
* **a rise not yet finished**: the plateau is the highest bin seen; the ``plateau_level`` rule
  rejects data that stop on a steep rise (a draw peaking above the cap: the class target is
  served), but a rise that flattens slowly can pass it, and then every level is read too high
  and the cap comes out too low;
* **shape differences**: the estimator assumes the draw's curve is the nominal one shifted; a draw
  whose rise is steeper or flatter than nominal (shear modulus, friction angle) moves the
  crossings without moving the peak as much (offline: up to 0.022 of the 0.03 budget on dry sand);
  a soil whose peak does not follow its free slip is not refined correctly;
* **measurement bias**: the slip axis is the limiter's shear slip from the *estimated* wheel-centre
  speed; a biased speed estimate shifts every bin and so the cap, one for one;
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

__all__ = ["CapRefiner", "CapRefinerConfig", "peak_from_rise", "rise_crossing_slip",
           "thrust_peak_offset"]


@dataclass(frozen=True)
class CapRefinerConfig:
    """Parameters of :class:`CapRefiner` (slips are unitless SAE slip, distances m).

    Parameters
    ----------
    band : largest departure of the served cap from the class target (0.1).
    probe : cap above the class target served until a crossing is confirmed (default 0.0: the
        crossing lies on the rise, below any cap near the peak).
    bin_width : slip bin width (0.02).
    s_lo, s_hi : slip range of the bins (0.02 .. 0.9).
    memory_m : m of wheel surface travel over which old samples fade by 1/e (*assumption*: 8 m).
    min_bin_weight : samples (forgetting-weighted) a bin needs to count (*assumption*: 5, 50 ms).
    level_lo, level_hi : share of the plateau between which a bin counts as *on the rise*
        (0.3 .. 0.9: below, the thrust is mostly the free-slip foot; above, the curve is too flat
        for its level to place the slip).
    max_bin_weight : a rise bin's weight in the mean of the crossings is capped here (20), so the
        cruise bin, which collects thousands of samples, does not hide the others.
    min_plateau_span : slip by which the plateau bin must lie above a rise bin (0.04).
    plateau_level : the plateau is confirmed only when a second bin reaches this share of the
        highest one (0.95): the curve has flattened, so the data did not stop on the rise.
    max_slip_rate : 1/s, samples with a faster-changing slip are dropped (*assumption*: 2 /s).
    max_cap_rate_per_m : largest change of the served cap per metre of wheel travel (0.05).
    """

    band: float = 0.1
    probe: float = 0.0
    bin_width: float = 0.02
    s_lo: float = 0.02
    s_hi: float = 0.9
    memory_m: float = 8.0
    min_bin_weight: float = 5.0
    level_lo: float = 0.3
    level_hi: float = 0.9
    max_bin_weight: float = 20.0
    min_plateau_span: float = 0.04
    plateau_level: float = 0.95
    max_slip_rate: float = 2.0
    max_cap_rate_per_m: float = 0.05

    def __post_init__(self) -> None:
        for name in ("band", "bin_width", "memory_m", "min_bin_weight", "max_bin_weight",
                     "min_plateau_span", "max_slip_rate", "max_cap_rate_per_m"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"CapRefinerConfig.{name} must be finite and > 0, got {v!r}")
        if not 0.0 < self.level_lo < self.level_hi < 1.0:
            raise ValueError("CapRefinerConfig: need 0 < level_lo < level_hi < 1, got "
                             f"{self.level_lo!r}, {self.level_hi!r}")
        if not self.level_hi < self.plateau_level < 1.0:
            raise ValueError("CapRefinerConfig.plateau_level must be in (level_hi, 1), got "
                             f"{self.plateau_level!r}")
        if not 0.0 <= self.probe <= self.band:
            raise ValueError(f"CapRefinerConfig.probe must be in [0, band], got {self.probe!r}")
        if not 0.0 <= self.s_lo < self.s_hi <= 1.0:
            raise ValueError("CapRefinerConfig: need 0 <= s_lo < s_hi <= 1")

    @property
    def levels(self) -> np.ndarray:
        """(L,) levels (share of the plateau) at which :func:`thrust_peak_offset` is tabulated."""
        return np.linspace(self.level_lo, self.level_hi, 61)


def rise_crossing_slip(slip: np.ndarray, thrust: np.ndarray, levels: np.ndarray) -> np.ndarray:
    """Slips where a thrust-slip curve first rises through ``levels`` times its maximum.

    Parameters
    ----------
    slip : (M,) slips, increasing.
    thrust : (M,) thrust at those slips (any unit: the crossings are scale-free).
    levels : (L,) shares of the maximum, in (0, 1).

    Returns
    -------
    (L,) crossing slips, linear between samples on the rise up to the maximum; NaN for a level the
    rise does not cross (a non-positive maximum, or the curve already above the level at its first
    sample).
    """
    s = np.asarray(slip, dtype=float)
    h = np.asarray(thrust, dtype=float)
    lv = np.asarray(levels, dtype=float)
    k_max = int(np.argmax(h))
    if not h[k_max] > 0.0 or k_max == 0:
        return np.full(lv.shape, np.nan)
    # the running maximum up to the peak is monotone, so each level is crossed once on it
    rise = np.maximum.accumulate(h[:k_max + 1]) / h[k_max]
    out = np.interp(lv, rise, s[:k_max + 1], left=np.nan, right=np.nan)
    return np.where(lv > rise[0], out, np.nan)


def thrust_peak_offset(slip: np.ndarray, thrust: np.ndarray, net_peak_slip: float,
                       config: CapRefinerConfig | None = None) -> np.ndarray:
    """``delta(level) = s_R(level) - s_T``: the crossings of a *nominal* curve at ``config.levels``
    minus that curve's net-traction peak ``net_peak_slip`` (the class target).

    ``slip`` (M,) and ``thrust`` (M,) sample the class's nominal gross-thrust curve at its static
    load (any unit). Returns (L,) offsets, one per level of ``config.levels``; all NaN when the
    nominal curve shows no rise (the cap is then served unrefined).
    """
    cfg = config or CapRefinerConfig()
    return rise_crossing_slip(slip, thrust, cfg.levels) - float(net_peak_slip)


def peak_from_rise(slips: np.ndarray, means: np.ndarray, weights: np.ndarray,
                   offsets: np.ndarray, config: CapRefinerConfig) -> float | None:
    """The draw's peak slip from a binned thrust-slip curve and the class's offsets (step 2-3).

    Parameters
    ----------
    slips : (B,) mean slip per bin.
    means : (B,) mean thrust per bin (any unit: only shares of the plateau are used).
    weights : (B,) weight per bin; bins below ``config.min_bin_weight`` are ignored.
    offsets : (L,) :func:`thrust_peak_offset` of the class at ``config.levels``.
    config : :class:`CapRefinerConfig`.

    Returns
    -------
    float, the weighted mean over the rise bins of ``slip_b - delta(m_b / m_max)``, or None when
    no bin is confirmed on the rise: fewer than 2 qualified bins, no second bin within
    ``plateau_level`` of the highest (no flat top seen), or no bin with a share of the plateau in
    ``[level_lo, level_hi]`` at least ``min_plateau_span`` below the highest bin.
    """
    ok = (weights >= config.min_bin_weight) & np.isfinite(means) & np.isfinite(slips)
    if ok.sum() < 2:
        return None
    x, y, w = slips[ok], means[ok], weights[ok]
    k_max = int(np.argmax(y))
    if not y[k_max] > 0.0:
        return None
    r = y / y[k_max]
    if np.sum(r >= config.plateau_level) < 2:
        return None                      # no flat top yet: the data may stop on the rise
    lv = config.levels
    good = np.isfinite(offsets)
    rise = ((r >= max(config.level_lo, lv[good].min() if good.any() else 1.0))
            & (r <= min(config.level_hi, lv[good].max() if good.any() else 0.0))
            & (x <= x[k_max] - config.min_plateau_span))
    if not rise.any():
        return None
    est = x[rise] - np.interp(r[rise], lv[good], offsets[good])
    wb = np.minimum(w[rise], config.max_bin_weight)
    return float(np.sum(wb * est) / np.sum(wb))


class CapRefiner:
    """Per-wheel online refinement of the traction cap (module docstring).

    Parameters
    ----------
    n_wheels : number of wheels N.
    config : :class:`CapRefinerConfig`.

    Attributes
    ----------
    weights, means, slips : (N, B) forgetting-weighted sample count, mean thrust (N) and mean
        slip per slip bin.
    peak_estimate : (N,) last confirmed estimate of the draw's peak slip per wheel (NaN: none).
    served : (N,) cap served at the last :meth:`cap` call (NaN before the first).
    """

    def __init__(self, n_wheels: int, config: CapRefinerConfig | None = None) -> None:
        self.n_wheels = int(n_wheels)
        self.config = config or CapRefinerConfig()
        cfg = self.config
        self.edges = np.arange(cfg.s_lo, cfg.s_hi + 1e-9, cfg.bin_width)
        nb = len(self.edges) - 1
        self.weights = np.zeros((self.n_wheels, nb))
        self.means = np.zeros((self.n_wheels, nb))
        self.slips = np.zeros((self.n_wheels, nb))
        self.peak_estimate = np.full(self.n_wheels, np.nan)
        self.served = np.full(self.n_wheels, np.nan)
        self._s_prev = np.full(self.n_wheels, np.nan)
        self._dist_since_cap = np.zeros(self.n_wheels)
        self._class_key: tuple | None = None

    def reset(self, wheels=None) -> None:
        """Forget every sample (all wheels, or an index): a new terrain class was served."""
        idx = slice(None) if wheels is None else wheels
        self.weights[idx] = 0.0
        self.means[idx] = 0.0
        self.slips[idx] = 0.0
        self.peak_estimate[idx] = np.nan

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
                self.slips[i, b] += (s[i] - self.slips[i, b]) / w
                self.weights[i, b] = w

    def peak(self, wheel: int, offsets) -> float | None:
        """Confirmed estimate of one wheel's peak slip (None when not confirmed; module docstring)."""
        return peak_from_rise(self.slips[wheel], self.means[wheel], self.weights[wheel],
                              np.asarray(offsets, dtype=float), self.config)

    def cap(self, class_target, offsets) -> np.ndarray:
        """Traction cap to serve per wheel.

        Parameters
        ----------
        class_target : (N,) or scalar, the class's traction target s_T (> 0).
        offsets : (L,) :func:`thrust_peak_offset` of that class, shared by the wheels; None or
            all NaN: no nominal curve (e.g. the class-free safe cap: the target is served
            unrefined).

        Returns
        -------
        (N,) traction cap: ``clip(estimate, s_T - band, s_T + band)`` where an estimate is
        confirmed, ``s_T + probe`` where not, rate-limited per metre of wheel travel.
        """
        cfg = self.config
        n = self.n_wheels
        base = np.broadcast_to(np.asarray(class_target, dtype=float), (n,)).copy()
        off = np.atleast_1d(np.asarray(math.nan if offsets is None else offsets, dtype=float))
        refine = bool(np.isfinite(off).any())
        key = tuple(np.round(base, 6))
        if self._class_key is not None and key != self._class_key:
            changed = np.abs(np.asarray(key) - np.asarray(self._class_key)) > 1e-9
            self.reset(np.flatnonzero(changed))     # another class: its curve is another curve
            self.served[changed] = np.nan
        self._class_key = key
        if not refine:
            self._dist_since_cap[:] = 0.0
            self.served = base
            return base
        want = base.copy()
        for i in range(n):
            if not np.isfinite(base[i]):
                continue
            est = self.peak(i, off)
            self.peak_estimate[i] = np.nan if est is None else est
            want[i] = base[i] + cfg.probe if est is None else est
        want = np.clip(want, base - cfg.band, base + cfg.band)
        step = cfg.max_cap_rate_per_m * self._dist_since_cap
        prev = np.where(np.isfinite(self.served), self.served, want)
        out = prev + np.clip(want - prev, -step, step)
        self._dist_since_cap[:] = 0.0
        self.served = out
        return out
