"""The online predictor: one :class:`~terrainml.stream.message.DesiredSlip` per base-rate tick.

Chain per tick (design §11)::

    sample ─ check_sample ─ ClockGate ─ HealthMonitor ─ OnlineEstimator.step ─ RingBuffer ─┬─ policy ─ DesiredSlip
                                                                      every hop (0.5 s):    └─ classify latest window

* :func:`terrainml.stream.sample.check_sample` rejects anything that is not a sample with
  :class:`~terrainml.stream.sample.InvalidSample` (the one exception :meth:`Predictor.step`
  raises); the clock policy (:mod:`terrainml.stream.clock`) decides which stamps are ticks.

* Estimation is :class:`terrainml.estimation.online.OnlineEstimator` (the same step code the
  offline ``estimate_run`` loops over); windows and features are the offline window and feature
  code applied to the ring buffer's rows (see :mod:`terrainml.stream.classify`).
* Classification runs at most once per hop, on the latest 2 s window, and only when that window
  passes the offline steady rules. Any exception inside it is caught: the tick is served with
  ``fallback=True, fallback_reason="classifier_error"`` until a later classification succeeds.
* Nothing non-finite reaches the output: non-finite inputs invalidate their sensor group
  (:mod:`terrainml.stream.health`), non-finite estimator outputs make ``estimator_ok`` false and
  are replaced (slip 0, state ``idle``), and the message layer checks again.
* Samples with a duplicate or late ``t_s`` are dropped and counted: :meth:`Predictor.step`
  returns ``None`` for them (the only departure from "one output per input"). A ``t_s`` off the
  timeline (a clock jump) is served as a ``clock_jump`` fallback tick; K consistent ones re-anchor
  the stream, restarting the estimator, health, window buffer and classification.
* The classification thread runs under the interpreter's own GIL switch interval: the predictor
  changes nothing process-wide (lowering it measured no better, often worse, for the paced
  per-tick p99; figures in ``docs/stream.md``, Performance).
"""

from __future__ import annotations

import logging
import math
import time
from collections import deque
from collections.abc import Mapping
from concurrent.futures import ThreadPoolExecutor
from functools import partial
from pathlib import Path
from typing import Any, Callable, Protocol, Sequence

import numpy as np
import pandas as pd

from terrainml.classes import TERRAIN_CLASSES
from terrainml.estimation.online import OnlineEstimator
from terrainml.features.windows import WindowSpec
from terrainml.lookup.policy import PolicyDecision, TargetTable
from terrainml.robot import RobotSpec, load_robot
from terrainml.schema import WHEEL_STATES
from terrainml.stream.classify import load_serving_model
from terrainml.stream.clock import ACCEPT, JUMP, MAX_GAP_S, REANCHOR, REANCHOR_AFTER, ClockGate
from terrainml.stream.fusion import TerrainFilter, confirm_windows_for
from terrainml.stream.health import HealthMonitor, InputCounters
from terrainml.stream.message import DesiredSlip
from terrainml.stream.policy import NO_CLASS_ID, NO_CLASS_NAME, SERVE_P, decide, safe_cap_for
from terrainml.stream.sample import InvalidSample, check_sample

__all__ = ["InvalidSample", "Predictor", "RingBuffer", "make_predictor"]

log = logging.getLogger("terrainml.stream")

_TIME_REASONS = ("no_t_s", "bad_t_s", "t_s_not_finite")
#: distance the robot must cover between two classification attempts (m): none standing still
MIN_MOVE_M = 0.01


def _is_label(name: str) -> bool:
    """Logged labels and simulator truth: never seen by the serving path."""
    return name in ("terrain", "run_id") or name.startswith("gt_")


class Estimator(Protocol):
    def step(self, sample: dict) -> dict: ...


class WindowClassifierLike(Protocol):
    """What the predictor needs from a classifier: probabilities for a window, or None."""

    class_ids: Sequence[int]

    def classify(self, window: pd.DataFrame) -> np.ndarray | None: ...


# --------------------------------------------------------------------------- ring buffer
class RingBuffer:
    """Fixed-capacity buffer of estimator rows (dicts) with O(1) append.

    Numeric fields are kept in a preallocated float array, everything else (wheel states,
    run id) in an object array; :meth:`frame` returns the rows in time order as a DataFrame,
    the same layout as the offline EST table.
    """

    def __init__(self, capacity: int):
        if capacity < 1:
            raise ValueError("RingBuffer capacity must be >= 1")
        self.capacity = int(capacity)
        self._num_keys: list[str] | None = None
        self._obj_keys: list[str] = []
        self._num: np.ndarray | None = None
        self._obj: np.ndarray | None = None
        self._i = 0
        self.count = 0
        self._index: dict[str, tuple[int, int]] | None = None
        self._view_keys: dict[Callable[[str], bool], tuple[list[str], frozenset]] = {}

    def _init(self, row: dict) -> None:
        num, obj = [], []
        for k, v in row.items():
            if isinstance(v, (bool, np.bool_)):
                num.append(k)
            elif isinstance(v, (int, float, np.integer, np.floating)):
                num.append(k)
            else:
                obj.append(k)
        self._num_keys, self._obj_keys = num, obj
        self._bool_keys = {k for k in num if isinstance(row[k], (bool, np.bool_))}
        self._num = np.full((self.capacity, len(num)), np.nan)
        self._obj = np.empty((self.capacity, len(obj)), dtype=object)

    def append(self, row: dict) -> None:
        if self._num_keys is None:
            self._init(row)
        i = self._i
        num = self._num
        for j, k in enumerate(self._num_keys):  # type: ignore[arg-type]
            v = row.get(k, math.nan)
            try:
                num[i, j] = v  # type: ignore[index]
            except (TypeError, ValueError, OverflowError):  # e.g. a str, or an int beyond float
                num[i, j] = math.nan  # type: ignore[index]
        for j, k in enumerate(self._obj_keys):
            self._obj[i, j] = row.get(k)  # type: ignore[index]
        self._i = (i + 1) % self.capacity
        self.count = min(self.count + 1, self.capacity)

    def clear(self) -> None:
        """Forget every row (a new timeline); the field layout of the first row is kept."""
        self._i = 0
        self.count = 0

    @property
    def full(self) -> bool:
        return self.count == self.capacity

    def snapshot(self) -> tuple[np.ndarray, np.ndarray] | None:
        """Copy of the rows in time order (two arrays; tens of microseconds), or None if empty.

        Taken on the tick path; :meth:`to_frame` turns it into a DataFrame later, on the
        classification thread, so the tick never pays for building a DataFrame (the field
        names are fixed by the first row, so they need no copy).
        """
        if self._num_keys is None:
            return None
        if self.full:
            order = np.r_[self._i:self.capacity, 0:self._i]
        else:
            order = np.arange(self.count)
        return self._num[order], self._obj[order]  # type: ignore[index]

    def to_frame(self, snap: tuple[np.ndarray, np.ndarray] | None) -> pd.DataFrame:
        """DataFrame (count, n_fields) of a :meth:`snapshot`, the offline EST table's layout."""
        if snap is None:
            return pd.DataFrame()
        num, obj = snap
        cols: dict[str, np.ndarray] = {}
        for j, k in enumerate(self._num_keys):  # type: ignore[arg-type]
            cols[k] = num[:, j] > 0.5 if k in self._bool_keys else num[:, j]
        for j, k in enumerate(self._obj_keys):
            cols[k] = obj[:, j]
        return pd.DataFrame(cols, copy=False)

    def frame(self) -> pd.DataFrame:
        """Rows in time order, oldest first: DataFrame, shape (count, n_fields)."""
        return self.to_frame(self.snapshot())

    def column_view(self, snap: tuple[np.ndarray, np.ndarray] | None,
                    skip: Callable[[str], bool] = lambda k: False) -> "SnapshotColumns":
        """Read-only mapping name -> column array (count,) of a :meth:`snapshot`, built on access.

        The same values as :meth:`to_columns` (flags as bool), but a column is sliced out only
        when the window code reads it: a short window reads about 20 of the ring's 70-odd fields.
        """
        if snap is None:
            return SnapshotColumns({}, set(), snap, ([], frozenset()))
        if self._index is None:
            self._index = {k: (0, j) for j, k in enumerate(self._num_keys)}  # type: ignore[arg-type]
            self._index.update({k: (1, j) for j, k in enumerate(self._obj_keys)})
        # the fields ``skip`` leaves are the same on every call (names are fixed by the first
        # row): filter them once per skip function, not on every update
        keys = self._view_keys.get(skip)
        if keys is None:
            kept = [k for k in self._index if not skip(k)]
            keys = self._view_keys[skip] = (kept, frozenset(kept))
        return SnapshotColumns(self._index, self._bool_keys, snap, keys)

    def to_columns(self, snap: tuple[np.ndarray, np.ndarray] | None,
                   skip: Callable[[str], bool] = lambda k: False) -> dict[str, np.ndarray]:
        """Column arrays (count,) of a :meth:`snapshot`, the same values as :meth:`to_frame`'s
        columns (flags as bool), without building a DataFrame; fields where ``skip(name)`` is
        true are left out (labels, which the serving path must not see). The eager form of
        :meth:`column_view`."""
        return dict(self.column_view(snap, skip))


class SnapshotColumns(Mapping):
    """Mapping name -> column of a ring snapshot (:meth:`RingBuffer.column_view`), lazy.

    Fields the view was asked to skip (labels) are absent. Numeric columns are views of the
    snapshot (float64), flags bool, other fields object arrays.
    """

    def __init__(self, index: Mapping[str, tuple[int, int]], bool_keys: set,
                 snap: tuple[np.ndarray, np.ndarray] | None, keys: tuple[list[str], frozenset]):
        self._keys, self._set = keys     # the names kept (skip already applied), and as a set
        self._index = index
        self._bool_keys = bool_keys
        self._snap = snap

    def __contains__(self, name: object) -> bool:
        return name in self._set

    def __getitem__(self, name: str) -> np.ndarray:
        if name not in self._set:
            raise KeyError(name)
        part, j = self._index[name]
        col = self._snap[part][:, j]  # type: ignore[index]
        return col > 0.5 if name in self._bool_keys else col

    def __iter__(self):
        return iter(self._keys)

    def __len__(self) -> int:
        return len(self._keys)


# --------------------------------------------------------------------------- predictor
class Predictor:
    """Online desired-slip predictor (design §10-11).

    Parameters
    ----------
    robot : RobotSpec
    table : desired-slip table with ``target(class_id, state) -> float``
        (:class:`terrainml.lookup.table.DesiredSlipTable`).
    classifier : object with ``class_ids`` and ``classify(window_df) -> probs | None``
        (:class:`terrainml.stream.classify.WindowClassifier`), or None (always fallback).
    estimator : object with ``step(sample) -> dict`` (an EST row); default
        ``OnlineEstimator(robot, preset)``.
    rate_hz : base rate, Hz. window_s, hop_s : s, window length and online hop (used when
        ``window_spec`` is None; design §8: 2.0 and 0.5 online).
    window_spec : the model's :class:`~terrainml.features.windows.WindowSpec` (its window length
        and online hop size the ring buffer and the classification rate).
    stale_m : m (default 3.0). More than this travelled since the last classification →
        ``stale_classification`` fallback. The age counts distance (the EKF's body speed
        integrated over ticks), not time: a robot standing still keeps its class.
    serve_p : fused posterior below this → ``uncertain_classification`` fallback (default 0.6).
    fusion : dict of :class:`~terrainml.stream.fusion.TerrainFilter` settings (``length_m``,
        ``alpha``, ``eps``, ``drift``, ``threshold``, ``confirm_windows``; the last defaults to
        :func:`~terrainml.stream.fusion.confirm_windows_for` the hop: 3 at 0.1 s, 1 at 0.5 s).
    max_age_s : s or None (default None: off). An optional wall-time limit on the age of the
        last classification, on top of ``stale_m``. silent_s : s, health rule.
    classify_lag_ticks : 0 (default) classifies inline on the hop tick. L > 0 runs the
        classification in a background thread and applies its result exactly L ticks later
        (deterministic: the tick waits for it if needed); the tick path then only snapshots
        the ring buffer, which keeps per-tick latency low when samples arrive in real time.
        The classification age still counts from the window's last tick.
    class_names : names of all class ids (default the eight of design §6.1).
    max_clock_gap_s : s, > 0 (default 1.0). Largest step between consecutive ticks of one
        timeline; a larger step either way is a clock jump (:mod:`terrainml.stream.clock`).
    reanchor_after : int >= 1 (default 5). Consecutive consistent off-timeline samples (K) that
        re-anchor the stream on a new timeline. Re-anchoring restarts the estimator (a fresh
        ``OnlineEstimator`` when the predictor built it; an injected estimator's ``reset()`` if it
        has one, else it is kept), the health monitor, the window buffer and classification.
    """

    def __init__(self, robot: RobotSpec, table: TargetTable,
                 classifier: WindowClassifierLike | None = None,
                 estimator: Estimator | None = None, *, preset: str = "robust",
                 rate_hz: float = 100.0, window_s: float = 2.0, hop_s: float = 0.5,
                 max_age_s: float | None = None, silent_s: float = 0.2, classify_lag_ticks: int = 0,
                 class_names: Sequence[str] = TERRAIN_CLASSES, max_clock_gap_s: float = MAX_GAP_S,
                 reanchor_after: int = REANCHOR_AFTER, window_spec: WindowSpec | None = None,
                 stale_m: float = 3.0, serve_p: float = SERVE_P,
                 fusion: Mapping[str, float] | None = None, sensors: Sequence[str] | None = None):
        self.robot = robot
        self.table = table
        self.classifier = classifier
        warm = estimator is None
        # a re-anchored stream needs a fresh estimator: build one the same way
        self._estimator_factory: Callable[[], Estimator] | None = None
        if estimator is None:
            self._estimator_factory = partial(OnlineEstimator, robot, preset)
            estimator = self._estimator_factory()
        self.estimator = estimator
        if window_spec is not None:
            rate_hz, window_s = window_spec.rate_hz, window_spec.window_s
            hop_s = window_spec.online_hop_s
        self.window_spec = window_spec
        self.rate_hz = float(rate_hz)
        self.window_s = float(window_s)
        self.hop_s = float(hop_s)
        self.max_age_s = None if max_age_s is None else float(max_age_s)
        self.serve_p = float(serve_p)
        self.class_names = list(class_names)
        self.counters = InputCounters()
        self.clock = ClockGate(self.counters, max_gap_s=max_clock_gap_s, reanchor_after=reanchor_after)
        # health only on the model's sensor groups (design §9, issue #17): a robot without IMU
        # is served by a model that does not use it; the EKF's own freshness rule requires the
        # IMU, so without it the estimator's flag is not read (a silent group, or a state that
        # is not finite, still makes the tick unhealthy)
        self.health = HealthMonitor(robot, silent_s=silent_s, sensors=sensors)
        self.sensors = None if sensors is None else list(sensors)
        self._estimator_flag = "imu" in self.health.monitored
        # fixed wheels constrain only forward speed and yaw rate: without steering or an IMU the
        # EKF's lateral speed is unobserved and drifts (180 m/s on a BorealTC run without IMU)
        self._lateral_observed = robot.has_steering or self._estimator_flag
        self._raw_columns = tuple(getattr(classifier, "raw_columns", ()) or ())
        self.health.counters = self.counters
        self.ring = RingBuffer(int(round(self.window_s * self.rate_hz)))
        self.n = robot.n_wheels
        self.seq = 0
        self._last_attempt_t: float | None = None
        self._probs: np.ndarray | None = None
        self._class_t: float | None = None
        self._classifier_error = False
        self.n_classifications = 0
        self.n_classifier_errors = 0
        self.n_estimator_errors = 0
        self.n_unsteady_windows = 0
        self.classify_ms: deque[float] = deque(maxlen=10000)  # bounded: flat memory
        self.wait_ms: deque[float] = deque(maxlen=10000)
        self.classify_lag_ticks = int(classify_lag_ticks)
        self._executor: Any = None
        self._pending: Any = None
        self._pending_age = 0
        self._slip_keys = [f"slip{i}" for i in range(1, self.n + 1)]
        self._state_keys = [f"state{i}" for i in range(1, self.n + 1)]
        self._vlong_keys = [f"v_long{i}_mps" for i in range(1, self.n + 1)]
        self._state_vars = ("ekf_vx_mps", "ekf_vy_mps", "ekf_yaw_rate_radps")
        # wheel states and speeds of the last estimated tick (what a clock_jump tick serves with)
        self._last_states: list[str] = ["idle"] * self.n
        self._last_v_long: list[float] = [0.0] * self.n
        # distance travelled (m): the clock of classification age and fusion
        self.odometer_m = 0.0
        self._t_prev: float | None = None
        self._odo_at_attempt: float | None = None
        fusion = {"confirm_windows": confirm_windows_for(self.hop_s), **dict(fusion or {})}
        self.filter = TerrainFilter(len(self._class_ids()), stale_m=stale_m, **fusion)
        cap_names = [self._name(c) for c in self._class_ids()]
        self._cap_classes = cap_names if hasattr(table, "class_names") else None
        self._cap_table = safe_cap_for(table, self._class_ids(), cap_names)
        if warm:
            self.warm_up(preset)

    def warm_up(self, preset: str = "robust") -> None:
        """Run a throwaway OnlineEstimator at rest, so the first real tick is not slow.

        The EKF's compiled kernels load on first use (about 0.2 s); doing that here keeps the
        first served tick inside its deadline. The predictor's own state is not touched.
        """
        n = self.n
        sample: dict[str, Any] = {"t_s": 0.0, "imu_ax_mps2": 0.0, "imu_ay_mps2": 0.0,
                                  "imu_az_mps2": 9.81, "imu_yaw_rate_radps": 0.0,
                                  "cam_vx_mps": 0.0, "cam_vy_mps": 0.0, "cam_yaw_rate_radps": 0.0,
                                  "cam_yaw_rad": 0.0}
        for i in range(1, n + 1):
            sample.update({f"wheel{i}_omega_radps": 0.0, f"wheel{i}_steer_rad": 0.0,
                           f"wheel{i}_current_a": 0.0})
        try:
            est = OnlineEstimator(self.robot, preset)
            est.step(sample)
            est.step({**sample, "t_s": 0.01})
        except Exception as exc:  # noqa: BLE001 - warm-up is an optimisation only
            log.debug("warm-up skipped: %s", exc)

    # ------------------------------------------------------------------ build
    @classmethod
    def from_model_dir(cls, model_dir: str | Path, *, robot: RobotSpec | str | None = None,
                       preset: str | None = None, trusted_keys: Sequence[str | Path] | None = None,
                       **kwargs: Any) -> "Predictor":
        """Predictor for a verified model artifact ``runs/NAME`` (model, manifest, slip table).

        ``trusted_keys``: public keys (``KEY.pub``) one of which must have signed the artifact.
        """
        served = load_serving_model(model_dir, robot=robot, trusted_keys=trusted_keys)
        return cls(served.robot, served.table, served.classifier,
                   preset=preset or served.preset, class_names=served.class_names,
                   window_s=served.window_s, hop_s=served.hop_s, rate_hz=served.rate_hz,
                   window_spec=served.window_spec, **{"sensors": served.sensors, **kwargs})

    # ------------------------------------------------------------------ tick
    def step(self, sample: Mapping[str, Any]) -> DesiredSlip | None:
        """Process one base-rate sample (canonical column names + ``t_s``).

        Parameters
        ----------
        sample : mapping of str keys to values, with ``t_s`` (s) a finite real number (``int``,
            ``float`` or a numpy scalar; not a bool, not a string). Values of the wrong type or
            non-finite only invalidate their sensor group (:mod:`terrainml.stream.health`).

        Returns
        -------
        DesiredSlip, one per tick, every number finite; or None when the sample is dropped: a
        duplicate or late ``t_s`` (clock policy, :mod:`terrainml.stream.clock`; counted in
        ``self.counters``). A ``t_s`` off the timeline is served as a fallback tick with
        ``fallback_reason="clock_jump"``; the K-th consistent one re-anchors the stream.

        Raises
        ------
        InvalidSample
            A ``ValueError`` (:mod:`terrainml.stream.sample`), when ``sample`` is not a sample:
            not a mapping (None, a string, a list, ...), a key that is not a str, no ``t_s``, or a
            ``t_s`` that is not a real number (a string, a bool, None) or not finite (NaN, inf,
            an int beyond float range). It is counted first (``bad_time`` for the ``t_s`` cases,
            ``not_a_sample`` otherwise) and the predictor's state is otherwise unchanged. It is
            the only exception ``step`` raises: estimator, classifier and policy failures are
            served as fallback ticks.
        """
        t_start = time.perf_counter()
        try:
            t = check_sample(sample)
        except InvalidSample as exc:
            if exc.reason in _TIME_REASONS:
                self.counters.bad_time += 1
            else:
                self.counters.not_a_sample += 1
            raise
        verdict = self.clock.check(t)
        if verdict == JUMP:
            return self._clock_jump_tick(t, t_start)
        if verdict == REANCHOR:
            self._restart()
        elif verdict != ACCEPT:
            return None
        clean, fresh = self.health.sanitise(sample)  # type: ignore[arg-type]
        healthy, _silent = self.health.update(t, fresh)

        row = self._estimate(clean)
        est_ok = healthy and row is not None and (bool(row.get("estimator_ok", True)) or not self._estimator_flag)
        if row is not None:
            for k in self._raw_columns:  # columns the model's windows read that the EKF does not pass
                if k not in row:
                    row[k] = clean.get(k, math.nan)
        slips, states, v_long = [0.0] * self.n, ["idle"] * self.n, [0.0] * self.n
        if row is not None:
            try:
                est_ok = self._read_row(row, slips, states, v_long) and est_ok
            except (TypeError, ValueError) as exc:  # a row we cannot read: unhealthy tick
                self.n_estimator_errors += 1
                log.warning("estimator row unreadable at t=%.3f s: %s", t, exc)
                slips, states, v_long = [0.0] * self.n, ["idle"] * self.n, [0.0] * self.n
                est_ok = False
            self.ring.append(row)
        self._last_states, self._last_v_long = states, v_long
        self._advance_odometer(t, row if est_ok else None)

        self._maybe_classify(t)

        age = None if self._class_t is None else t - self._class_t
        dec = self._decide(age, est_ok, states, v_long, t)
        return self._message(t, dec, slips, states, age, est_ok, t_start)

    def _advance_odometer(self, t: float, row: dict | None) -> None:
        """Integrate the EKF's body speed over the tick; the fusion filter ages by that distance.

        The lateral speed counts only where it is observed (steered wheels or an IMU); a
        skid-steer robot without IMU integrates |v_x|.

        An unhealthy tick adds nothing (its speed is not trusted); dt is bounded by the clock
        policy (<= max_clock_gap_s)."""
        dt = 0.0 if self._t_prev is None else t - self._t_prev
        self._t_prev = t
        if row is None or not dt > 0:
            return
        try:
            vx, vy = float(row.get("ekf_vx_mps", 0.0)), float(row.get("ekf_vy_mps", 0.0))
            v = math.hypot(vx, vy) if self._lateral_observed else abs(vx)
        except (TypeError, ValueError):
            return
        if math.isfinite(v):
            d = v * dt
            self.odometer_m += d
            self.filter.predict(d)

    def _clock_jump_tick(self, t: float, t_start: float) -> DesiredSlip:
        """A stamp off the timeline: the fallback row for the last estimated wheel states.

        The estimator, health monitor, ring buffer and classifier do not see the sample (its
        time would corrupt them); measured slip is served as 0 (not measured on this tick).
        """
        dec = self._decide(None, False, self._last_states, self._last_v_long, t, clock_jump=True)
        return self._message(t, dec, [0.0] * self.n, self._last_states, None, False, t_start)

    def safe_cap_traction(self) -> float:
        """Traction target of the safe cap served on fallback (design §10)."""
        cap = self._cap_table.safe_cap(self._cap_classes)
        return float(cap.target("traction"))

    def fallback_reason(self, age_s: float | None, est_ok: bool, clock_jump: bool = False) -> str:
        """The reason this tick cannot serve a class ("" when it can), by priority (design §11)."""
        if clock_jump:
            return "clock_jump"
        if not est_ok:
            return "estimator_unhealthy"
        if self._classifier_error and self.filter.posterior is None:
            return "classifier_error"
        if self.filter.posterior is None:
            return "no_classification"
        if self.filter.stale or (self.max_age_s is not None and age_s is not None
                                 and age_s > self.max_age_s):
            return "stale_classification"
        if self.filter.best()[1] < self.serve_p:
            return "uncertain_classification"
        return ""

    def _decide(self, age: float | None, est_ok: bool, states: list[str], v_long: list[float],
                t: float, clock_jump: bool = False) -> PolicyDecision:
        reason = self.fallback_reason(age, est_ok, clock_jump)
        try:
            k, post = self.filter.best()
            cid = self._class_ids()[k] if k >= 0 and not reason else None
            return decide(cid, post, reason, self.table, self._cap_table, self._cap_classes,
                          states=states, v_long=v_long,
                          class_name=self._name(cid) if cid is not None else NO_CLASS_NAME)
        except Exception as exc:  # noqa: BLE001 - a broken table/policy must not stop serving
            log.warning("policy failed at t=%.3f s (serving zero slip): %s", t, exc)
            return PolicyDecision(class_id=NO_CLASS_ID, class_name=NO_CLASS_NAME, confidence=0.0,
                                  slip_desired=(0.0,) * self.n, fallback=True,
                                  reason=reason or "classifier_error")

    def _message(self, t: float, dec: PolicyDecision, slips: list[float], states: list[str],
                 age: float | None, est_ok: bool, t_start: float) -> DesiredSlip:
        slip_des = [v if math.isfinite(v) else 0.0 for v in dec.slip_desired]
        msg = DesiredSlip(
            t_s=t, seq=self.seq, slip_desired=slip_des, slip_measured=slips, wheel_state=states,
            terrain_class=dec.class_id,
            terrain_name=NO_CLASS_NAME if dec.fallback else self._name(dec.class_id),
            confidence=dec.confidence, class_probabilities=self._full_probs(len(self.class_names)),
            classification_age_s=-1.0 if age is None else float(age),
            fallback=dec.fallback, fallback_reason=dec.reason, estimator_ok=est_ok,
        )
        self.seq += 1
        msg.processing_ms = (time.perf_counter() - t_start) * 1e3
        return msg

    def _restart(self) -> None:
        """A new timeline (clock policy): estimation, health, windows and classification start over."""
        if self._estimator_factory is not None:
            self.estimator = self._estimator_factory()
        else:
            reset = getattr(self.estimator, "reset", None)
            if callable(reset):
                reset()
        self.health.reset()
        self.ring.clear()
        self._pending = None  # a window of the old timeline: its result is never applied
        self._probs = None
        self._class_t = None
        self._last_attempt_t = None
        self._classifier_error = False
        self.filter.reset()
        self._t_prev = None
        self._odo_at_attempt = None

    # ------------------------------------------------------------------ parts
    def _read_row(self, row: dict, slips: list, states: list, v_long: list) -> bool:
        """Fill per-wheel slip, state and v_long from an EST row; False if the state is not finite.

        Non-finite slip becomes 0 (e.g. no camera: slip unavailable); a wheel with a
        non-finite v_long is served as idle.
        """
        ok = True
        for k in self._state_vars:
            v = row.get(k, 0.0)
            if v is None or not math.isfinite(float(v)):
                ok = False
        for i in range(self.n):
            s = row.get(self._slip_keys[i])
            slips[i] = float(s) if s is not None and math.isfinite(float(s)) else 0.0
            st = row.get(self._state_keys[i], "idle")
            v = row.get(self._vlong_keys[i], 0.0)
            v = float(v) if v is not None and math.isfinite(float(v)) else math.nan
            if math.isnan(v):
                st, v = "idle", 0.0
            states[i] = st if st in WHEEL_STATES else "idle"
            v_long[i] = v
        return ok

    def _estimate(self, clean: dict) -> dict | None:
        try:
            return self.estimator.step(clean)
        except Exception as exc:  # noqa: BLE001 - never crash the serving loop
            self.n_estimator_errors += 1
            if self.n_estimator_errors <= 3:
                log.warning("estimator step failed at t=%.3f s: %s", clean.get("t_s", math.nan), exc)
            return None

    def _class_ids(self) -> list[int]:
        if self.classifier is None:
            return list(range(len(self.class_names)))
        return [int(c) for c in self.classifier.class_ids]

    def _name(self, cid: int) -> str:
        if cid == NO_CLASS_ID:
            return NO_CLASS_NAME
        return self.class_names[cid] if 0 <= cid < len(self.class_names) else str(cid)

    def _full_probs(self, k: int) -> list[float]:
        out = [0.0] * k
        if self._probs is not None:
            for cid, p in zip(self._class_ids(), self._probs):
                if 0 <= cid < k:
                    out[cid] = float(p)
        return out

    def _maybe_classify(self, t: float) -> None:
        if self.classifier is None:
            return
        # 1. a pending background classification is applied exactly `classify_lag_ticks` later
        if self._pending is not None:
            fut, t_win, due = self._pending
            self._pending_age += 1
            if self._pending_age >= due:
                self._pending = None
                c0 = time.perf_counter()
                try:
                    self._apply(fut.result(), t_win)
                except Exception as exc:  # noqa: BLE001
                    self._fail(t_win, exc)
                self.wait_ms.append((time.perf_counter() - c0) * 1e3)
        # 2. at most one new classification per hop, on the latest full window
        if not self.ring.full or self._pending is not None:
            return
        if self._last_attempt_t is not None and t - self._last_attempt_t < self.hop_s - 1e-9:
            return
        # standing still the window holds nothing new about the ground: skip (and save the cost)
        if self._odo_at_attempt is not None and self.odometer_m - self._odo_at_attempt < MIN_MOVE_M:
            return
        self._last_attempt_t = t
        self._odo_at_attempt = self.odometer_m
        snap = self.ring.snapshot()
        if self.classify_lag_ticks > 0:
            if self._executor is None:
                self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="classify")
            self._pending = (self._executor.submit(self._timed_classify, snap), t,
                             self.classify_lag_ticks)
            self._pending_age = 0
            return
        try:
            self._apply(self._timed_classify(snap), t)
        except Exception as exc:  # noqa: BLE001 - classification must never crash serving
            self._fail(t, exc)

    def _timed_classify(self, snap: tuple[np.ndarray, np.ndarray] | None) -> np.ndarray | None:
        c0 = time.perf_counter()
        try:
            return self.classify_snapshot(snap)
        finally:
            self.classify_ms.append((time.perf_counter() - c0) * 1e3)

    def classify_snapshot(self, snap: tuple[np.ndarray, np.ndarray] | None) -> np.ndarray | None:
        """Probabilities for the latest window of a ring :meth:`~RingBuffer.snapshot` (or None).

        The serving path: the classifier reads the snapshot's columns in place
        (:meth:`RingBuffer.column_view`, labels left out), no DataFrame is built.
        """
        fast = getattr(self.classifier, "classify_columns", None)
        if fast is not None:  # column arrays straight from the ring: no DataFrame
            return fast(self.ring.column_view(snap, _is_label))
        return self.classifier.classify(self.ring.to_frame(snap))  # type: ignore[union-attr]

    def _apply(self, probs: Any, t_win: float) -> None:
        if probs is None:  # latest window not steady: keep the previous classification
            self.n_unsteady_windows += 1
            return
        p = np.asarray(probs, dtype=float).ravel()
        if p.shape[0] != len(self._class_ids()) or not np.all(np.isfinite(p)) or p.sum() <= 0:
            raise ValueError(f"classifier returned invalid probabilities {p!r}")
        p = np.clip(p, 0.0, None)
        self._probs = p / p.sum()
        self._class_t = t_win
        self._classifier_error = False
        self.n_classifications += 1
        self.filter.update(self._probs)

    def _fail(self, t: float, exc: BaseException) -> None:
        self.n_classifier_errors += 1
        if self.n_classifier_errors <= 3:
            log.warning("classification failed at t=%.3f s (serving fallback): %s", t, exc)
        self._probs = None
        self._class_t = None
        self._classifier_error = True
        self.filter.reset()

    def close(self) -> None:
        """Stop the background classification thread (if any)."""
        if self._executor is not None:
            self._executor.shutdown(wait=True)
            self._executor = None

    def stats(self) -> dict[str, Any]:
        """Counters for the end-of-stream summary (stderr) and tests."""
        return {**self.counters.as_dict(), "emitted": self.seq,
                "classifications": self.n_classifications,
                "classifier_errors": self.n_classifier_errors,
                "unsteady_windows": self.n_unsteady_windows,
                "estimator_errors": self.n_estimator_errors,
                "distance_m": self.odometer_m, "terrain_changes": self.filter.n_changes}


def make_predictor(model: str | Path, robot: str | None = None, preset: str | None = None,
                   **kwargs: Any) -> Predictor:
    """Convenience for the CLI: ``Predictor.from_model_dir`` with a robot name or path."""
    return Predictor.from_model_dir(model, robot=load_robot(robot) if robot else None,
                                    preset=preset, **kwargs)
