"""Input hygiene and estimator health for the online predictor (SYSTEM §11, robustness).

Rules
-----
* **Ordering**: a sample whose ``t_s`` is not finite, equal to the last accepted one (duplicate)
  or earlier (out of order) is dropped and counted; nothing is emitted for it.
* **Validity**: a sensor group (``wheels``, ``steer``, ``current``, ``imu``, ``cam``, ``cmd``) is
  *fresh* on a tick when all its data columns are present and finite and its ``{group}_valid``
  flag (if the sample carries one) is true. Otherwise the group's columns are set to NaN and
  ``{group}_valid=False`` before the estimator sees the sample (so the EKF drops those rows and
  never sees a stale or non-finite value).
* **Health**: a monitored group (wheels, current, imu; steer when the robot steers; cam when it
  has a camera) that has not been fresh for more than ``silent_s`` (default 0.2 s) makes the
  estimator unhealthy. Health returns as soon as every monitored group is fresh again.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from terrainml.robot import RobotSpec
from terrainml.schema import VALID_GROUPS, column_map, group_columns

def _is_finite_number(v: Any) -> bool:
    if isinstance(v, bool) or v is None:
        return False
    try:
        return math.isfinite(float(v))
    except (TypeError, ValueError):
        return False


@dataclass
class InputCounters:
    """Counts of inputs the predictor dropped or repaired (all reported by ``terrainml predict``)."""

    accepted: int = 0
    duplicate: int = 0
    out_of_order: int = 0
    bad_time: int = 0
    invalid_group_ticks: dict[str, int] = field(default_factory=dict)

    @property
    def dropped(self) -> int:
        return self.duplicate + self.out_of_order + self.bad_time

    def as_dict(self) -> dict[str, Any]:
        return {"accepted": self.accepted, "duplicate": self.duplicate,
                "out_of_order": self.out_of_order, "bad_time": self.bad_time,
                "invalid_group_ticks": dict(self.invalid_group_ticks)}


class OrderGate:
    """Drop samples with non-finite, duplicate or decreasing ``t_s`` (counted in ``counters``)."""

    def __init__(self, counters: InputCounters | None = None):
        self.counters = counters or InputCounters()
        self.last_t_s: float | None = None

    def accept(self, sample: dict) -> bool:
        t = sample.get("t_s")
        if not _is_finite_number(t):
            self.counters.bad_time += 1
            return False
        t = float(t)
        if self.last_t_s is not None:
            if t == self.last_t_s:
                self.counters.duplicate += 1
                return False
            if t < self.last_t_s:
                self.counters.out_of_order += 1
                return False
        self.last_t_s = t
        self.counters.accepted += 1
        return True


class HealthMonitor:
    """Sanitise each sample's sensor groups and track how long each has been silent.

    Parameters
    ----------
    robot : RobotSpec, decides the monitored groups and wheel columns.
    silent_s : float, s. A monitored group silent for longer than this marks the estimator unhealthy.
    """

    def __init__(self, robot: RobotSpec, silent_s: float = 0.2):
        self.robot = robot
        self.silent_s = float(silent_s)
        n = robot.n_wheels
        spec = column_map(n)
        # the same columns decide a group's validity as in schema.validate_run_table
        self.group_cols: dict[str, list[str]] = {
            g: [c for c in group_columns(g, n)
                if (spec[c].required or g in ("cam", "cmd")) and c != "cam_confidence"]
            for g in VALID_GROUPS}
        self.monitored: list[str] = ["wheels", "current", "imu"]
        if robot.has_steering:
            self.monitored.append("steer")
        if robot.has_camera:
            self.monitored.append("cam")
        self.last_fresh_t: dict[str, float] = {}
        self._t0: float | None = None
        self.counters: InputCounters | None = None

    def reset(self) -> None:
        self.last_fresh_t.clear()
        self._t0 = None

    def sanitise(self, sample: dict) -> tuple[dict, dict[str, bool]]:
        """Return (clean sample, fresh flag per group). The input dict is not modified.

        Non-finite or non-numeric values of a group invalidate the whole group for this tick.
        """
        out = dict(sample)
        out["t_s"] = float(sample["t_s"])
        fresh: dict[str, bool] = {}
        nan = float("nan")
        for g, cols in self.group_cols.items():
            present = [c for c in cols if c in sample]
            flag = sample.get(f"{g}_valid", True)
            ok = bool(present) and len(present) == len(cols) and (flag is True or flag == 1)
            if ok:
                for c in cols:
                    if not _is_finite_number(sample[c]):
                        ok = False
                        break
            if ok:
                for c in cols:
                    out[c] = float(sample[c])
            else:
                for c in present:
                    out[c] = nan
                if (present or g in self.monitored) and self.counters is not None:
                    d = self.counters.invalid_group_ticks
                    d[g] = d.get(g, 0) + 1
            if present or g in self.monitored:
                out[f"{g}_valid"] = ok
            fresh[g] = ok
        # optional extras (imu_yaw_rad, cam_confidence, commands, ...): finite numbers or NaN;
        # only run_id and simulator truth may carry strings
        for k, v in sample.items():
            if k.endswith("_valid") or k in ("t_s", "run_id") or k.startswith("gt_"):
                continue
            if k not in self._all_group_cols:
                out[k] = float(v) if _is_finite_number(v) else nan
        return out, fresh

    @property
    def _all_group_cols(self) -> set[str]:
        s = getattr(self, "_cols_cache", None)
        if s is None:
            s = {c for cols in self.group_cols.values() for c in cols}
            self._cols_cache = s
        return s

    def update(self, t_s: float, fresh: dict[str, bool]) -> tuple[bool, list[str]]:
        """Record this tick's fresh groups; return (healthy, silent groups)."""
        if self._t0 is None:
            self._t0 = t_s
        silent = []
        for g in self.monitored:
            if fresh.get(g, False):
                self.last_fresh_t[g] = t_s
            last = self.last_fresh_t.get(g, self._t0)
            if t_s - last > self.silent_s + 1e-9:
                silent.append(g)
        return (not silent), silent
