"""Filter consistency (NIS) and accuracy against simulator truth.

NIS (thesis eq. 4.14) ``eps_k = y_k^T S_k^-1 y_k`` is chi-square distributed with ``dof_k``
(rows used at tick k) degrees of freedom when the filter is consistent: mean NIS/dof ~ 1 and
~95 % of ticks inside the two-sided 95 % chi-square band. NIS/dof << 1 means R (or P) is
conservative, >> 1 that the filter is over-confident or the model is biased (e.g. zero-slip
wheel rows on soft ground). The thesis explains why its R makes NIS saturate (§6.1.1): read
NIS as a diagnostic, not a tuning target.

A mean NIS/dof outside :data:`NIS_SANE_BAND` (0.1-10, a decade either side of 1: far wider than
the thesis's saturation, so only a filter that is badly mis-tuned for the robot leaves it) is
reported as ``warning`` in :func:`consistency_report` with what to check (real logs
gave 0.011 and 17 with no word said), and logged.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np
import pandas as pd
from scipy import stats
from scipy.ndimage import uniform_filter1d

from terrainml.estimation.run import Diagnostics
from terrainml.schema import EST_VX, EST_VY, EST_YAW_RATE

THESIS_INNOVATION_VAR = {"cam_vx": 7e-6, "cam_vy": 4e-6, "cam_yaw_rate": 3.81e-4}  # thesis §6.2
#: mean NIS/dof outside this band: the filter's noise model does not fit the robot's sensors
NIS_SANE_BAND = (0.1, 10.0)

log = logging.getLogger("terrainml.estimation")


def nis_warning(mean_nis_per_dof: float) -> str | None:
    """A message saying what to check when mean NIS/dof is outside :data:`NIS_SANE_BAND`, else None."""
    lo, hi = NIS_SANE_BAND
    v = float(mean_nis_per_dof)
    if not np.isfinite(v) or lo <= v <= hi:
        return None
    if v < lo:
        return (f"mean NIS/dof {v:.3g} < {lo:g}: the measurement noise (R) or the state covariance is far "
                "too large for these sensors, so the filter ignores its measurements; check the robot "
                "spec's sensor noise and the units of the inputs (e.g. deg/s read as rad/s), or try "
                "--preset thesis")
    return (f"mean NIS/dof {v:.3g} > {hi:g}: the filter is over-confident or its model does not fit "
            "(wrong units or sign of a channel, a mis-mounted IMU, wheel radius or track, low-rate "
            "wheel data resampled with steps); check the robot spec and the topic map before trusting "
            "slip and wheel states")


def nis_band(dof, level: float = 0.95) -> tuple[np.ndarray, np.ndarray]:
    """Two-sided chi-square band (lower, upper) for each dof (NaN where dof == 0)."""
    dof = np.asarray(dof, dtype=float)
    lo = np.where(dof > 0, stats.chi2.ppf((1 - level) / 2, np.maximum(dof, 1)), np.nan)
    hi = np.where(dof > 0, stats.chi2.ppf(1 - (1 - level) / 2, np.maximum(dof, 1)), np.nan)
    return lo, hi


def consistency_report(est: pd.DataFrame, diag: Diagnostics | None = None) -> dict[str, Any]:
    """Mean and median NIS/dof, fraction inside the 95 % band, innovation statistics per row.

    Returns
    -------
    dict with ``mean_nis_per_dof``, ``median_nis_per_dof``, ``frac_in_95_band``, ``n_ticks_updated``
    and, if ``diag`` is given, ``innovations``: {row: {mean, var, mean_S, n}} and ``n_gated``.
    """
    nis = est["nis"].to_numpy(dtype=float)
    dof = est["nis_dof"].to_numpy(dtype=float)
    ok = (dof > 0) & np.isfinite(nis)
    out: dict[str, Any] = {"n_ticks_updated": int(ok.sum())}
    if ok.any():
        r = nis[ok] / dof[ok]
        lo, hi = nis_band(dof[ok])
        out.update(mean_nis_per_dof=float(r.mean()), median_nis_per_dof=float(np.median(r)),
                   frac_in_95_band=float(((nis[ok] >= lo) & (nis[ok] <= hi)).mean()))
        msg = nis_warning(out["mean_nis_per_dof"])
        if msg is not None:
            out["warning"] = msg
            log.warning("%s", msg)
    else:
        out.update(mean_nis_per_dof=float("nan"), median_nis_per_dof=float("nan"), frac_in_95_band=float("nan"))
    if diag is not None:
        inn = {}
        for k, name in enumerate(diag.rows):
            y = diag.innovation[:, k]
            s = diag.innovation_var[:, k]
            m = np.isfinite(y)
            if m.sum() > 1:
                inn[name] = {"mean": float(y[m].mean()), "var": float(y[m].var()),
                             "mean_S": float(s[m].mean()), "n": int(m.sum())}
        out["innovations"] = inn
        out["n_gated"] = int(diag.n_gated)
    return out


def steady_mask_from_truth(est: pd.DataFrame, accel_max_mps2: float = 0.15, min_speed_mps: float = 0.2,
                           smooth_s: float = 0.3) -> np.ndarray:
    """Ticks of steady motion by true kinematics: true body speed above ``min_speed_mps`` and
    its rate of change (and the yaw rate's) below ``accel_max_mps2`` (per s), both smoothed over
    ``smooth_s``; a 0.5 s margin after every non-steady tick is removed as well."""
    t = est["t_s"].to_numpy(float)
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.01
    w = max(1, int(round(smooth_s / dt)))
    vx = est["gt_vx_mps"].to_numpy(float)
    vy = est["gt_vy_mps"].to_numpy(float)
    r = est["gt_yaw_rate_radps"].to_numpy(float) if "gt_yaw_rate_radps" in est else np.zeros_like(vx)
    dvx = uniform_filter1d(np.gradient(vx, t), w)
    dvy = uniform_filter1d(np.gradient(vy, t), w)
    dr = uniform_filter1d(np.gradient(r, t), w)
    ok = (np.hypot(vx, vy) >= min_speed_mps) & (np.hypot(dvx, dvy) < accel_max_mps2) & (np.abs(dr) < accel_max_mps2)
    # margin: steady only if steady for the previous 0.5 s as well
    m = max(1, int(round(0.5 / dt)))
    bad = np.convolve((~ok).astype(float), np.ones(m), mode="full")[: len(ok)] > 0
    return ok & ~bad


def truth_metrics(est: pd.DataFrame, n_wheels: int | None = None, t_min_s: float = 0.0,
                  steady_from: str = "kinematics") -> dict[str, Any]:
    """Accuracy against simulator truth (needs ``gt_*`` columns).

    Steady slip MAE per wheel: mean |slip_i - gt_slip_i| over steady ticks where the slip is
    available and finite. ``steady_from="kinematics"`` (default) takes steady ticks from the
    true body motion (:func:`steady_mask_from_truth`); ``"gt_state"`` from the simulator's
    ``gt_state{i}`` labels. Also the error of the run's mean steady slip
    (``|mean(slip) - mean(gt_slip)|``, what the thesis reports per run). Body-velocity RMSE is
    ``sqrt(mean((vx - gt_vx)^2 + (vy - gt_vy)^2))``; yaw-rate RMSE likewise.
    """
    if n_wheels is None:
        n_wheels = sum(1 for c in est.columns if c.startswith("slip") and c[4:].isdigit())
    t = est["t_s"].to_numpy()
    keep = t >= t_min_s
    out: dict[str, Any] = {}
    if {"gt_vx_mps", "gt_vy_mps"} <= set(est.columns):
        ex = est[EST_VX].to_numpy() - est["gt_vx_mps"].to_numpy()
        ey = est[EST_VY].to_numpy() - est["gt_vy_mps"].to_numpy()
        e2 = (ex ** 2 + ey ** 2)[keep]
        out["vel_rmse_mps"] = float(np.sqrt(np.nanmean(e2)))
        if "slip_available" in est.columns:  # camera healthy (robots with a camera)
            ok = est["slip_available"].to_numpy(bool)[keep]
            if ok.any():
                out["vel_rmse_cam_ok_mps"] = float(np.sqrt(np.nanmean(e2[ok])))
    if "gt_yaw_rate_radps" in est.columns:
        er = (est[EST_YAW_RATE].to_numpy() - est["gt_yaw_rate_radps"].to_numpy())[keep]
        out["yaw_rate_rmse_radps"] = float(np.sqrt(np.nanmean(er ** 2)))
    maes, mean_errs, all_err = [], [], []
    steady_kin = steady_mask_from_truth(est) if {"gt_vx_mps", "gt_vy_mps"} <= set(est.columns) else None
    for i in range(1, n_wheels + 1):
        if f"gt_slip{i}" not in est.columns:
            continue
        s = est[f"slip{i}"].to_numpy(dtype=float)
        g = est[f"gt_slip{i}"].to_numpy(dtype=float)
        if steady_from == "gt_state" and f"gt_state{i}" in est.columns:
            steady = est[f"gt_state{i}"].astype(str).to_numpy() == "steady"
        elif {"gt_vx_mps", "gt_vy_mps"} <= set(est.columns):
            steady = steady_kin
        else:
            steady = est[f"state{i}"].astype(str).to_numpy() == "steady"
        m = steady & np.isfinite(s) & np.isfinite(g) & keep
        if m.sum() == 0:
            maes.append(float("nan"))
            mean_errs.append(float("nan"))
            continue
        err = np.abs(s[m] - g[m])
        all_err.append(err)
        maes.append(float(err.mean()))
        mean_errs.append(float(abs(s[m].mean() - g[m].mean())))
    if maes:
        out["steady_slip_mae_per_wheel"] = maes
        out["steady_slip_mean_error_per_wheel"] = mean_errs
        out["steady_slip_mae"] = float(np.concatenate(all_err).mean()) if all_err else float("nan")
        out["steady_slip_mean_error"] = float(np.nanmean(mean_errs)) if np.isfinite(mean_errs).any() else float("nan")
    if any(f"gt_state{i}" in est.columns for i in range(1, n_wheels + 1)):
        agree, total, per = 0, 0, {}
        for i in range(1, n_wheels + 1):
            if f"gt_state{i}" not in est.columns:
                continue
            gs = est[f"gt_state{i}"].astype(str).to_numpy()
            es = est[f"state{i}"].astype(str).to_numpy()
            for name in ("traction", "braking", "steady"):
                m = (gs == name) & keep
                a, n = int((es[m] == name).sum()), int(m.sum())
                pa, pn = per.get(name, (0, 0))
                per[name] = (pa + a, pn + n)
                agree, total = agree + a, total + n
        out["state_agreement"] = agree / total if total else float("nan")
        out["state_agreement_per_state"] = {k: (a / n if n else float("nan")) for k, (a, n) in per.items()}
    return out


def min_state_duration_s(est: pd.DataFrame, n_wheels: int) -> float:
    """Shortest completed state segment over all wheels (s); the first and last segments of a
    run are excluded (they are cut by the run's ends)."""
    t = est["t_s"].to_numpy()
    best = float("inf")
    for i in range(1, n_wheels + 1):
        s = est[f"state{i}"].astype(str).to_numpy()
        change = np.flatnonzero(s[1:] != s[:-1]) + 1
        if len(change) >= 2:
            best = min(best, float(np.min(np.diff(t[change]))))
    return best
