"""Input hygiene and estimator health for the online predictor (design §11, robustness).

Rules
-----
* **Ordering** of time stamps is the clock policy of :mod:`terrainml.stream.tick.clock`.
* **Validity**: a sensor group (``wheels``, ``steer``, ``current``, ``imu``, ``cam``, ``cmd``) is
  *fresh* on a tick when all its data columns are present and finite and its ``{group}_valid``
  flag (if the sample carries one) is true. Otherwise the group's columns are set to NaN and
  ``{group}_valid=False`` before the estimator sees the sample (so the EKF drops those rows and
  never sees a stale or non-finite value). A value that is not a number (a string, a list, an
  integer too large for a float, ...) counts as non-finite. Extras pass as finite floats or NaN;
  ``run_id`` and simulator truth (``gt_*``) may also be strings. A finite value beyond its
  channel's physical limit (:data:`terrainml.schema.PHYSICAL_LIMITS`: 1000 A, 1000 rad/s,
  1000 m/s^2, 100 m/s, 1e4 rad; e.g. a current of 1e308 A) invalidates its group the same way,
  counted per column (``out_of_range``); an extra beyond its limit becomes NaN. A
  ``wheel{i}_*`` key of a wheel the robot does not have (``wheel4_*`` on three wheels) is
  ignored, counted (``unknown_wheel_keys``) and warned the first time.
* **Health**: a monitored group (wheels, current, imu; steer when the robot steers; cam when it
  has a camera) that has not been fresh for more than ``silent_s`` (default 0.2 s) makes the
  estimator unhealthy. Health returns as soon as every monitored group is fresh again.
  A model that records the sensor groups it needs (``sensors`` in its manifest, design §9)
  narrows the monitored groups to those (wheels always): a robot without IMU, camera or
  current sensing is then served by a model that does not use them.
* **Said live**: a monitored group that goes silent past ``silent_s`` is named on the log
  (``terrainml predict``: stderr) the tick it does, with its columns, "never seen" when it has
  not been fresh since the start (e.g. a log without its IMU topic), and again when it returns;
  each group's silent episodes are counted (``silent_episodes``). The first
  :data:`WARN_EPISODES` episodes of a group are warned, then every 100th. When the source knows
  that the group's topic publishes NaN or infinite values (``invalid_hint``, a live ROS 2
  source's :meth:`~terrainml.stream.tick.inputs.InputWatch.group_invalid`), the episode is said as
  *invalid values* ("... valid again"), not as a silence. A group whose values arrive finite with
  its ``{group}_valid`` flag false (ingest's rule judged them: a tracking camera's confidence below
  the topic map's ``min_confidence``) is said as *flagged invalid by its source*. A group the source does not map is
  removed from ``monitored`` by the predictor (:meth:`Predictor.set_mapped_groups`).
"""

from __future__ import annotations

import logging
import math
import re
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np

from terrainml.robot import RobotSpec
from terrainml.schema import VALID_GROUPS, column_map, group_columns, physical_limit
from terrainml.stream.tick.sample import TIME_REASONS

_NAN = float("nan")
log = logging.getLogger("terrainml.stream")
_WHEEL_KEY = re.compile(r"wheel(\d+)_")
#: silent episodes per group warned one by one (then every 100th)
WARN_EPISODES = 5
#: s a sensor group may go without a fresh sample before a tick is unhealthy
SILENT_S = 0.2
#: model sensor group (manifest ``sensors``) -> health group
SENSOR_TO_GROUP = {"wheels": "wheels", "currents": "current", "imu": "imu", "cam": "cam"}


def _is_finite_number(v: Any) -> bool:
    if isinstance(v, (bool, np.ndarray)) or v is None:  # an array is not a number, even of size 1
        return False
    try:
        return math.isfinite(float(v))
    except (TypeError, ValueError, ArithmeticError):  # ArithmeticError: int beyond float range
        return False


def _flag_true(flag: Any) -> bool:
    """A ``{group}_valid`` flag says valid: True, 1 or 1.0 (never an error, whatever its type)."""
    if flag is True:
        return True
    if isinstance(flag, (int, float, np.number, np.bool_)):
        return bool(flag == 1)
    return False


def _label(v: Any) -> Any:
    """``run_id`` / ``gt_*``: a string or a finite number passes, anything else becomes NaN."""
    return v if isinstance(v, str) or _is_finite_number(v) else _NAN


@dataclass
class InputCounters:
    """Counts of inputs the predictor dropped or repaired (all reported by ``terrainml predict``)."""

    accepted: int = 0
    duplicate: int = 0
    out_of_order: int = 0
    bad_time: int = 0       # InvalidSample: no t_s, t_s not a number or not finite
    not_a_sample: int = 0   # InvalidSample: not a mapping, or a key that is not a str
    clock_jump: int = 0     # served as clock_jump fallback (off the timeline)
    reanchors: int = 0      # times the stream re-anchored on a new timeline
    invalid_group_ticks: dict[str, int] = field(default_factory=dict)
    silent_episodes: dict[str, int] = field(default_factory=dict)  # times each group went silent
    out_of_range: dict[str, int] = field(default_factory=dict)  # column -> samples beyond its limit
    unknown_wheel_keys: dict[str, int] = field(default_factory=dict)  # wheel{i}_* beyond n_wheels

    @property
    def dropped(self) -> int:
        return self.duplicate + self.out_of_order + self.bad_time + self.not_a_sample

    def count_invalid(self, reason: str) -> None:
        """Count an :class:`~terrainml.stream.tick.sample.InvalidSample` by its ``reason``: a ``t_s``
        that is missing, not a number or not finite is ``bad_time``, anything else ``not_a_sample``."""
        if reason in TIME_REASONS:
            self.bad_time += 1
        else:
            self.not_a_sample += 1

    def as_dict(self) -> dict[str, Any]:
        return {"accepted": self.accepted, "duplicate": self.duplicate,
                "out_of_order": self.out_of_order, "bad_time": self.bad_time,
                "not_a_sample": self.not_a_sample, "clock_jump": self.clock_jump,
                "reanchors": self.reanchors,
                "invalid_group_ticks": dict(self.invalid_group_ticks),
                "silent_episodes": dict(self.silent_episodes),
                "out_of_range": dict(self.out_of_range),
                "unknown_wheel_keys": dict(self.unknown_wheel_keys)}


class HealthMonitor:
    """Sanitise each sample's sensor groups and track how long each has been silent.

    Parameters
    ----------
    robot : RobotSpec, decides the monitored groups and wheel columns.
    silent_s : float, s. A monitored group silent for longer than this marks the estimator unhealthy.
    sensors : the model's sensor groups (``wheels``, ``currents``, ``imu``, ``cam``) or None (every
        group the robot has). Only these are monitored (wheels, and steer on a steered robot,
        always: the estimator needs them).
    """

    def __init__(self, robot: RobotSpec, silent_s: float = SILENT_S, sensors: Sequence[str] | None = None):
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
        if sensors is not None:
            wanted = {SENSOR_TO_GROUP.get(str(g), str(g)) for g in sensors} | {"wheels", "steer"}
            self.monitored = [g for g in self.monitored if g in wanted]
        self._limit = {c: physical_limit(c, n) for c in spec}  # every canonical column, once
        self.last_fresh_t: dict[str, float] = {}
        self._t0: float | None = None
        self._silent_now: set[str] = set()   # groups said silent and not yet back
        self.counters: InputCounters | None = None
        #: ``group -> bool``: the group's input brings invalid values (NaN, inf) rather than nothing
        #: (a live source's :meth:`~terrainml.stream.tick.inputs.InputWatch.group_invalid`); None: unknown
        self.invalid_hint: Callable[[str], bool] | None = None
        self._invalid_now: set[str] = set()  # groups said invalid (not silent) and not yet back
        #: groups whose values arrived finite with their ``{group}_valid`` flag false on their last
        #: tick that was not fresh: the source judged them (a tracking camera's low confidence),
        #: they are not silent
        self.flagged: set[str] = set()

    def reset(self) -> None:
        self.last_fresh_t.clear()
        self._t0 = None
        self._silent_now.clear()
        self.flagged.clear()

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
            key = f"{g}_valid"
            whole = bool(present) and len(present) == len(cols)
            flag_ok = _flag_true(sample.get(key, True))
            ok = whole and flag_ok
            if ok:
                for c in cols:
                    v = sample[c]
                    if not _is_finite_number(v):
                        ok = False
                        break
                    if abs(float(v)) > self._limit[c]:  # finite but beyond physics: broken
                        ok = False
                        if self.counters is not None:
                            d = self.counters.out_of_range
                            d[c] = d.get(c, 0) + 1
                        break
            if ok:
                for c in cols:
                    out[c] = float(sample[c])
            else:
                # (read only on a tick the group is not fresh: a fresh tick leaves it as is)
                if whole and not flag_ok and all(_is_finite_number(sample[c]) for c in cols):
                    self.flagged.add(g)      # values arrive, its source marks them invalid
                else:
                    self.flagged.discard(g)
                for c in present:
                    out[c] = nan
                if (present or g in self.monitored) and self.counters is not None:
                    d = self.counters.invalid_group_ticks
                    d[g] = d.get(g, 0) + 1
            if present or g in self.monitored or key in sample:
                out[key] = ok
            fresh[g] = ok
        # optional extras (imu_yaw_rad, cam_confidence, commands, ...): finite numbers or NaN;
        # only run_id and simulator truth may carry strings
        for k, v in sample.items():
            if k.endswith("_valid") or k == "t_s":
                continue
            if k == "run_id" or k.startswith("gt_"):
                out[k] = _label(v)
            elif k not in self._all_group_cols:
                if k.startswith("wheel") and k not in self._limit:
                    self._unknown_wheel_key(k)
                out[k] = float(v) if _is_finite_number(v) and abs(float(v)) <= self._limit_of(k) else nan
        return out, fresh

    def _unknown_wheel_key(self, key: str) -> None:
        """A ``wheel{i}_*`` key of a wheel the robot does not have (``wheel4_*`` on three wheels):
        counted, warned the first time (up to :data:`WARN_EPISODES` keys); its value is ignored."""
        m = _WHEEL_KEY.match(key)
        if m is None or self.counters is None:
            return
        idx = m.group(1)
        if len(idx) <= 6 and 1 <= int(idx) <= self.robot.n_wheels:  # (a 5,000-digit int raises)
            return
        d = self.counters.unknown_wheel_keys
        name = key if key in d or len(d) < 100 else "(others)"  # bounded against a hostile stream
        d[name] = d.get(name, 0) + 1
        if d[name] == 1 and len(d) <= WARN_EPISODES:
            log.warning("sample key %r names a wheel robot '%s' does not have (%d wheels): ignored",
                        key, self.robot.name, self.robot.n_wheels)

    def _limit_of(self, name: str) -> float:
        return self._limit.get(name, math.inf)  # unknown extras: only finiteness

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
                if g not in self._silent_now:
                    self._said_silent(g, t_s)
            elif g in self._silent_now:
                self._silent_now.discard(g)
                if self._episodes(g) <= WARN_EPISODES:
                    log.warning("sensor group %r %s again at t=%.3f s", g,
                                "valid" if g in self._invalid_now else "fresh", t_s)
                self._invalid_now.discard(g)
        return (not silent), silent

    def _episodes(self, g: str) -> int:
        return 0 if self.counters is None else self.counters.silent_episodes.get(g, 0)

    def _said_silent(self, g: str, t_s: float) -> None:
        """A monitored group just went silent: count the episode, name it on the log."""
        self._silent_now.add(g)
        n = self._episodes(g) + 1
        if self.counters is not None:
            self.counters.silent_episodes[g] = n
        invalid = self.invalid_hint is not None and self.invalid_hint(g)
        flagged = g in self.flagged and not invalid
        if invalid or flagged:
            self._invalid_now.add(g)
        if n <= WARN_EPISODES or n % 100 == 0:
            since = (f"last fresh at t={self.last_fresh_t[g]:.3f} s" if g in self.last_fresh_t
                     else "never seen since the start")
            if flagged:   # finite values its source marks invalid (e.g. low tracking confidence)
                log.warning("sensor group %r flagged invalid by its source at t=%.3f s (%s; columns %s; "
                            "%s_valid false, e.g. a tracking confidence below the topic map's "
                            "min_confidence): serving estimator_unhealthy until it is valid (episode %d)",
                            g, t_s, since, ", ".join(self.group_cols[g]), g, n)
            elif invalid:   # its topic publishes, with NaN or infinite values: not a silence
                log.warning("sensor group %r has invalid values (NaN or infinite) at t=%.3f s (%s; columns %s): "
                            "serving estimator_unhealthy until they are valid (episode %d)", g, t_s, since,
                            ", ".join(self.group_cols[g]), n)
            else:
                log.warning("sensor group %r silent at t=%.3f s (%s; columns %s): serving "
                            "estimator_unhealthy until it returns (episode %d)", g, t_s, since,
                            ", ".join(self.group_cols[g]), n)
