"""Per-mission metrics of the mission suite, from a plain time-series log (design §12, docs/missions.md).

Everything here works on a :class:`MissionLog` (numpy arrays on a uniform time grid, SI units), not
on the simulator, so each metric can be checked by hand on a made-up log
(``tests/experiments/test_mission_metrics.py``). :func:`mission_metrics` returns the row of the
report; the formulas (dt the grid step, sums over ticks k and wheels i):

==========================  ==================================================================
``distance_m``              sum_k |v_k| dt (true body speed)
``route_done``              the follower reached the last waypoint (``t_done_s`` not None)
``time_s``                  t_done - t_start when done, else the elapsed mission time
``longest_stall_s``         longest run of ticks with v_cmd >= 0.05 m/s and |v| < 0.2 v_cmd, x dt
``success``                 route_done and time_s <= 2 t_nominal and longest_stall_s <= 5 s and
                            max_sinkage_m < clearance_m
``energy_j``                sum_k P_batt,k dt (regeneration counted negative)
``energy_noregen_j``        sum_k max(P_batt,k, 0) dt
``energy_j_per_m``          energy_j / distance_m
``tractive_efficiency``     sum_{k loaded} max(DP v, 0)_k / sum_{k loaded} max(P_batt, 0)_k
``spin_share``              share of (tick, wheel) pairs with slip > 0.8 among ticks with v_cmd > 0
``max_sinkage_m``           max_{k,i} z_{k,i}
``rut_depth_m``             max_{k,i} rut_{k,i}
``slip_work_j_per_m``       sum_{k,i} max(F_i (omega_i R - v_long,i), 0)_k dt / distance_m
==========================  ==================================================================

A metric whose input the log lacks (e.g. no drawbar power) is NaN, never a made-up value.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

__all__ = ["CMD_MOVING_MPS", "MAX_STALL_S", "SPIN_SLIP", "STALL_SPEED_RATIO", "TIME_FACTOR",
           "MissionLog", "longest_stall_s", "mission_metrics", "summarise", "summarise_rows"]

SPIN_SLIP = 0.8            # a wheel "spins" above this slip
MAX_STALL_S = 5.0          # a stall longer than this fails the mission
TIME_FACTOR = 2.0          # the route must be done within this multiple of its nominal time
CMD_MOVING_MPS = 0.05      # commanded speed at or above which the robot is asked to move
STALL_SPEED_RATIO = 0.2    # stalled: true speed below this share of the commanded speed


@dataclass
class MissionLog:
    """A mission's time series on a uniform grid (n ticks, N wheels); SI units.

    Attributes
    ----------
    t_s : (n,) time, s, uniform step.
    x_m, y_m : (n,) true position of the robot's origin, world frame, m.
    speed_mps : (n,) true body speed, m/s.
    cmd_speed_mps : (n,) commanded body speed, m/s.
    slip : (n, N) true SAE slip per wheel.
    sinkage_m : (n, N) true sinkage per wheel, m.
    rut_m : (n, N) rut depth left behind each wheel, m (NaN when the physics has none).
    p_battery_w : (n,) battery power, W (negative while regenerating).
    p_drawbar_w : (n,) drawbar power DP v of the towed load or tool, W (NaN when unknown).
    p_slip_w : (n, N) slip power per wheel F (omega R - v_long), W.
    loaded : (n,) bool, a towed load or tool is attached and pulled.
    t_start_s : when the route starts (end of the start delay), s.
    t_done_s : when the route was completed, s (None: not completed).
    nominal_time_s : the route's nominal time, s (:meth:`Route.nominal_time_s`).
    clearance_m : sinkage at which the belly touches, m.
    extra : anything else carried along (not used by the metrics).
    """

    t_s: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    speed_mps: np.ndarray
    cmd_speed_mps: np.ndarray
    slip: np.ndarray
    sinkage_m: np.ndarray
    rut_m: np.ndarray
    p_battery_w: np.ndarray
    p_drawbar_w: np.ndarray
    p_slip_w: np.ndarray
    loaded: np.ndarray
    t_start_s: float
    t_done_s: float | None
    nominal_time_s: float
    clearance_m: float
    extra: dict = field(default_factory=dict)

    @property
    def dt_s(self) -> float:
        return float(self.t_s[1] - self.t_s[0]) if len(self.t_s) > 1 else 0.0

    def decimate(self, every: int) -> "MissionLog":
        """Every ``every``-th tick (for a stored trace); scalars unchanged."""
        kw: dict[str, Any] = {}
        for f in fields(self):
            v = getattr(self, f.name)
            kw[f.name] = v[::every] if isinstance(v, np.ndarray) else v
        return MissionLog(**kw)

    def arrays(self) -> dict[str, np.ndarray]:
        """The array fields, by name (for an .npz trace)."""
        return {f.name: getattr(self, f.name) for f in fields(self)
                if isinstance(getattr(self, f.name), np.ndarray)}


def longest_stall_s(speed_mps: np.ndarray, cmd_speed_mps: np.ndarray, dt_s: float) -> float:
    """Longest run of ticks asked to move (cmd >= 0.05 m/s) at under 20 % of the command, s."""
    cmd = np.asarray(cmd_speed_mps, dtype=float)
    stalled = (cmd >= CMD_MOVING_MPS) & (np.abs(np.asarray(speed_mps, dtype=float)) < STALL_SPEED_RATIO * cmd)
    best = run = 0
    for s in stalled:
        run = run + 1 if s else 0
        best = max(best, run)
    return best * float(dt_s)


def _nan_safe_sum(x: np.ndarray) -> float:
    x = np.asarray(x, dtype=float)
    return float("nan") if x.size and np.isnan(x).all() else float(np.nansum(x))


def mission_metrics(log: MissionLog) -> dict[str, Any]:
    """The metrics of one mission (formulas in the module docstring), JSON-ready floats and bools."""
    dt = log.dt_s
    dist = float(np.sum(np.abs(log.speed_mps)) * dt)
    per_m = 1.0 / dist if dist > 1e-6 else float("nan")
    done = log.t_done_s is not None
    t_end = float(log.t_s[-1]) if len(log.t_s) else log.t_start_s
    time_s = (float(log.t_done_s) if done else t_end) - log.t_start_s
    stall = longest_stall_s(log.speed_mps, log.cmd_speed_mps, dt)
    max_z = float(np.nanmax(log.sinkage_m)) if np.isfinite(log.sinkage_m).any() else float("nan")
    rut = float(np.nanmax(log.rut_m)) if np.isfinite(log.rut_m).any() else float("nan")
    energy = float(np.sum(log.p_battery_w) * dt)
    energy_noregen = float(np.sum(np.maximum(log.p_battery_w, 0.0)) * dt)
    loaded = np.asarray(log.loaded, dtype=bool)
    useful = _nan_safe_sum(np.maximum(log.p_drawbar_w[loaded], 0.0)) * dt
    spent = float(np.sum(np.maximum(log.p_battery_w[loaded], 0.0)) * dt)
    eta = useful / spent if spent > 0 and math.isfinite(useful) else float("nan")
    asked = log.cmd_speed_mps > 0
    spin = float(np.mean(log.slip[asked] > SPIN_SLIP)) if asked.any() else 0.0
    slip_work = float(np.sum(np.maximum(log.p_slip_w, 0.0)) * dt)
    success = bool(done and time_s <= TIME_FACTOR * log.nominal_time_s + 1e-9 and stall <= MAX_STALL_S
                   and (not math.isfinite(max_z) or max_z < log.clearance_m))
    return {
        "success": success, "route_done": bool(done), "time_s": time_s,
        "nominal_time_s": float(log.nominal_time_s), "time_ratio": time_s / log.nominal_time_s,
        "distance_m": dist, "longest_stall_s": stall,
        "energy_j": energy, "energy_noregen_j": energy_noregen,
        "energy_j_per_m": energy * per_m, "energy_noregen_j_per_m": energy_noregen * per_m,
        "tractive_efficiency": eta, "spin_share": spin,
        "max_sinkage_m": max_z, "rut_depth_m": rut, "clearance_m": float(log.clearance_m),
        "slip_work_j": slip_work, "slip_work_j_per_m": slip_work * per_m,
    }


# ------------------------------------------------------------------ summaries of report rows
SUMMARY_KEYS = ("time_s", "energy_j_per_m", "tractive_efficiency", "spin_share", "max_sinkage_m",
                "rut_depth_m", "slip_work_j_per_m", "demand_ratio")


def _stats(values) -> dict[str, float | None]:
    x = np.array([v for v in values if v is not None and math.isfinite(v)], dtype=float)
    if x.size == 0:
        return {"median": None, "p10": None, "p90": None, "mean": None}
    p10, med, p90 = np.percentile(x, [10, 50, 90])
    return {"median": float(med), "p10": float(p10), "p90": float(p90), "mean": float(x.mean())}


def summarise_rows(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Success rate and the distribution (median, p10, p90, mean) of :data:`SUMMARY_KEYS`."""
    out: dict[str, Any] = {"n": len(rows),
                           "success_rate": float(np.mean([r["success"] for r in rows])) if rows else None,
                           "route_done_rate": float(np.mean([r["route_done"] for r in rows])) if rows else None}
    for k in SUMMARY_KEYS:
        out[k] = _stats(r.get(k) for r in rows)
    return out


def summarise(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Report summary: overall, per family and per ``family/terrain``."""
    fams = sorted({r["family"] for r in rows})
    pairs = sorted({(r["family"], r["terrain"]) for r in rows})
    return {"overall": summarise_rows(rows),
            "by_family": {f: summarise_rows([r for r in rows if r["family"] == f]) for f in fams},
            "by_family_terrain": {f"{f}/{t}": summarise_rows([r for r in rows if r["family"] == f
                                                             and r["terrain"] == t]) for f, t in pairs}}
