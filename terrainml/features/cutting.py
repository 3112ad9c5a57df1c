"""Cutting steady windows from an EST table (design §8), offline and online with one function.

:func:`terrainml.features.windows.cut_windows` (the arrays by :func:`cut_window_arrays`) serves
both paths:

* offline (``online=False``): windows start at row 0 and hop ``spec.hop_s`` (2.0 s:
  non-overlapping, thesis §8.1) over a whole EST table;
* online (``online=True``): windows END at the last row and hop ``spec.online_hop_s`` (0.5 s)
  backwards, so a ring buffer holding exactly one window length of rows gives exactly one
  window, the latest. Serving does exactly that: its ring buffer (:mod:`terrainml.stream.tick.ring`)
  holds one window length of EST rows, and :class:`terrainml.stream.tick.classify.WindowClassifier`
  cuts the ring's columns every online hop.

Every per-row conversion is elementwise and every per-window reduction runs on the same rows
in the same order in both paths, so a window cut online is bit-identical to the same window cut
offline (``tests/features/test_windows.py`` and ``tests/stream/test_serving_windows.py``, the
serving path row by row, prove it within 1e-9 on features).

Steady rules (design §8); a window is kept only if all hold, and every rule counts the windows
it rejects (a window may fail several rules, so the counts may add up to more than the number
rejected):

``time_gap``       the rows span (T - 1) / rate_hz seconds within half a period (no missing ticks)
``wheel_state``    every wheel ``steady`` or ``idle`` for >= 90% of ticks
``speed``          mean body speed hypot(ekf_vx, ekf_vy) >= 0.2 m/s
``acceleration``   |mean ekf_ax| and |mean ekf_ay| < 0.15 m/s^2 over the window (EKF body
                   acceleration states, centripetal part included: steady arcs tighter than
                   0.15 m/s^2 lateral are rejected; ``spec.remove_centripetal`` uses dv/dt
                   instead). *Departure*: design §8 reads "mean |ax|"; the magnitude of the
                   mean is used because on rough or soft ground the body vibrates at 3-8 Hz
                   with 0.1-0.4 m/s^2 rms (roughness modulating thrust), so mean |ax| rejected
                   every cruise window on tilled soil while the robot held its speed. The
                   window's net acceleration is what says "not speeding up or slowing down".
``steering``       std of every wheel's steering angle (ekf_steer{i}_rad, else the encoder)
                   < 0.05 rad
``terrain_label``  at most one terrain label among the rows (unlabelled rows are ignored);
                   with ``spec.label_at = "end"`` a window straddling a terrain change is kept
                   and labelled with the terrain of its newest labelled row (the terrain under
                   the robot when the window ends, what serving must report), so a classifier
                   learns that a mixed signature belongs to one of the two real classes
``channel_valid``  every used channel valid (finite, its sensor group valid) for >= 95% of ticks

Raw windows (the CNN's input and the feature sets' input) hold the channels of
:mod:`terrainml.features.channels` as an array (C, T) per window, T = 200 at 100 Hz;
``spec.channels`` restricts the set (e.g. wheel channels only when the IMU is missing). Channel
names travel with the windows. Invalid samples inside a kept window (at most 5%) are filled by
linear interpolation over the window's valid samples (edge values held).
"""

from __future__ import annotations

from collections.abc import Mapping
from functools import lru_cache
from typing import Any

import numpy as np
import pandas as pd

from terrainml.features.channels import channel_column
from terrainml.features.window_spec import MOVING_STATES, RULES, STEADY_STATES, WindowSpec
from terrainml.robot import RobotSpec
from terrainml.schema import EST_VX, EST_VY, EST_YAW_RATE, wheel_col

__all__ = ["cut_window_arrays", "empty_window_meta"]


def _has(est: Any, name: str) -> bool:
    """Column ``name`` present in a DataFrame or a mapping of column arrays."""
    return name in (est if isinstance(est, Mapping) else est.columns)


def _n_rows(est: Any) -> int:
    if isinstance(est, Mapping):
        return int(len(next(iter(est.values())))) if est else 0
    return len(est)


def _text_col(est: Any, name: str) -> np.ndarray:
    """Column as an object array of str (wheel states, run ids)."""
    v = est[name]
    if isinstance(est, Mapping):
        return np.asarray(v, dtype=object).astype(str).astype(object)
    return v.astype(str).to_numpy(dtype=object)


def _float_col(est: Any, name: str, n: int) -> np.ndarray:
    if not _has(est, name):
        return np.full(n, np.nan)
    v = est[name]
    if isinstance(est, Mapping):  # column arrays (the online ring buffer): no pandas on the tick
        v = np.asarray(v)
        if v.dtype.kind in "fiub":
            return v.astype(np.float64, copy=False)
        v = pd.Series(v)
    if v.dtype.kind in "fiu":  # already numeric (the usual case): skip the parser
        return v.to_numpy(dtype=np.float64)
    return pd.to_numeric(v, errors="coerce").to_numpy(dtype=np.float64, na_value=np.nan)


def _bool_col(est: Any, name: str, n: int) -> np.ndarray:
    if not _has(est, name):
        return np.ones(n, dtype=bool)
    v = est[name]
    if isinstance(est, Mapping):
        v = np.asarray(v)
        if v.dtype == bool:
            return v
        if v.dtype.kind in "fiu":  # a float flag (ring buffer): the same rule as below
            return np.isfinite(v) & (v != 0)
        v = pd.Series(v)
    if v.dtype == bool:
        return v.to_numpy(dtype=bool)
    f = pd.to_numeric(v, errors="coerce").to_numpy(dtype=np.float64, na_value=np.nan)
    return np.isfinite(f) & (f != 0)


class _Columns:
    """Typed, memoised column access for one :func:`cut_windows` call.

    Each column is converted once (validity flags are shared by many channels) and the
    DataFrame-or-mapping test is made once, not per column: on the serving path (one short
    window cut from the ring's arrays) these conversions were most of an update's cost.
    """

    def __init__(self, est: Any):
        self.est = est
        self.is_map = isinstance(est, Mapping)
        self.names = est if self.is_map else frozenset(est.columns)
        self.n = _n_rows(est)
        self._float: dict[str, np.ndarray] = {}
        self._bool: dict[str, np.ndarray] = {}

    def has(self, name: str) -> bool:
        return name in self.names

    def float(self, name: str) -> np.ndarray:
        """Column as float64 (n,), NaN where missing or unparsable (read-only: shared)."""
        v = self._float.get(name)
        if v is None:
            raw = self.est[name] if self.is_map and name in self.names else None
            if name not in self.names:
                v = np.full(self.n, np.nan)
            elif isinstance(raw, np.ndarray) and raw.dtype == np.float64:
                v = raw  # the ring's float columns: used as they are
            else:
                v = _float_col(self.est, name, self.n)
            self._float[name] = v
        return v

    def bool(self, name: str) -> np.ndarray:
        """Flag column (n,): true where finite and non-zero; all true when missing."""
        v = self._bool.get(name)
        if v is None:
            v = self._bool[name] = (_bool_col(self.est, name, self.n) if name in self.names
                                    else np.ones(self.n, dtype=bool))
        return v

    def text(self, name: str) -> np.ndarray:
        return _text_col(self.est, name)



def _window_starts(n_rows: int, T: int, hop: int, online: bool) -> np.ndarray:
    if n_rows < T:
        return np.zeros(0, dtype=np.int64)
    if online:
        starts = np.arange(n_rows - T, -1, -hop)[::-1]
    else:
        starts = np.arange(0, n_rows - T + 1, hop)
    return starts.astype(np.int64)


def _steer_std(steer: np.ndarray) -> np.ndarray:
    """Std per wheel (rows) over finite samples; 0 where a wheel has none."""
    if not steer.shape[1] or (steer == steer[:, :1]).all():  # wheels held still (or none): 0
        return np.zeros(steer.shape[0])
    if np.isfinite(steer).all():  # the usual case: one vectorised reduction
        return steer.std(axis=1)
    out = np.zeros(steer.shape[0])
    for i, row in enumerate(steer):
        row = row[np.isfinite(row)]
        if row.size:
            out[i] = row.std()
    return out


def _fill_invalid(x: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Linear interpolation of invalid samples over the valid ones (edges held)."""
    if ok.all():
        return x
    idx = np.arange(x.size, dtype=np.float64)
    if not ok.any():
        return np.zeros_like(x)
    out = x.copy()
    out[~ok] = np.interp(idx[~ok], idx[ok], x[ok])
    return out


def _channel_plan(channels: tuple[str, ...], robot: RobotSpec
                  ) -> tuple[tuple[str, tuple[str, ...], float], ...]:
    """Each channel's (column, validity columns, scale), memoised per channel set and robot."""
    try:
        return _channel_plan_cached(channels, robot)
    except TypeError:  # a robot spec that cannot be hashed: work it out every time
        return _channel_plan_cached.__wrapped__(channels, robot)


@lru_cache(maxsize=64)
def _channel_plan_cached(channels: tuple[str, ...], robot: RobotSpec
                         ) -> tuple[tuple[str, tuple[str, ...], float], ...]:
    """Each channel's (column, validity columns, scale) for ``robot``, worked out once.

    Raises ValueError for a channel that names a wheel the robot does not have.
    """
    N = robot.n_wheels
    for c in channels:
        if c.startswith(("slip_", "current_")) and c.split("_")[1].isdigit() and int(c.split("_")[1]) > N:
            raise ValueError(f"channel {c!r} names a wheel the robot '{robot.name}' does not have "
                             f"(N = {N})")
    return tuple(channel_column(ch, robot) for ch in channels)


def cut_window_arrays(est: pd.DataFrame | Mapping[str, np.ndarray], robot: RobotSpec, spec: WindowSpec,
                      online: bool = False, run_id: str | None = None, *, with_meta: bool = True
                      ) -> tuple[np.ndarray, tuple[str, ...], pd.DataFrame | None, dict[str, Any]]:
    """The kept windows' arrays (X (n_kept, C, T), channel names, metadata or None) and the rule
    counts; parameters and counts as :func:`terrainml.features.windows.cut_windows` has them."""
    channels = spec.channels_for(robot)
    cols = _Columns(est)
    T = spec.n_samples
    starts = _window_starts(cols.n, T, spec.hop_samples(online), online)
    counts: dict[str, Any] = {"n_windows": int(len(starts)), "n_kept": 0, "n_rejected": 0}
    counts.update({r: 0 for r in RULES})
    counts["invalid_channels"] = {}
    C = len(channels)
    if len(starts) == 0:
        return np.zeros((0, C, T)), channels, empty_window_meta() if with_meta else None, counts
    rows = _RowArrays(cols, robot, spec, channels)
    counts["invalid_channels"] = rows.bad
    X_kept, meta_rows = [], []
    for s in starts:
        fails, labels = rows.fails(int(s), T)
        if fails:
            counts["n_rejected"] += 1
            for f in fails:
                counts[f] += 1
            continue
        X_kept.append(rows.window(int(s), T))
        meta_rows.append((int(s), int(labels[0]) if labels.size else -1, float(rows.t[s]), float(rows.t[s + T - 1])))
    counts["n_kept"] = len(X_kept)
    X = np.stack(X_kept) if X_kept else np.zeros((0, C, T))
    if not with_meta:
        return X, channels, None, counts
    if not X_kept:
        return X, channels, empty_window_meta(), counts
    return X, channels, _window_meta(cols, meta_rows, run_id), counts


def empty_window_meta() -> pd.DataFrame:
    """The metadata of no window: the columns of ``Windows.meta``, typed, zero rows."""
    return pd.DataFrame({"run_id": pd.Series([], dtype=object), "terrain": pd.Series([], dtype=np.int64),
                         "t_start_s": pd.Series([], dtype=float), "t_end_s": pd.Series([], dtype=float),
                         "start_index": pd.Series([], dtype=np.int64)})


def _window_meta(cols: "_Columns", meta_rows: list[tuple], run_id: str | None) -> pd.DataFrame:
    """The kept windows' metadata (run ids read only here: the serving path has none to read)."""
    n = cols.n
    if cols.has("run_id") and n:
        run_ids = cols.text("run_id")
    else:
        run_ids = np.full(n, run_id if run_id is not None else "", dtype=object)
    meta = pd.DataFrame([(str(run_ids[s]), lab_, t0, t1, s) for s, lab_, t0, t1 in meta_rows],
                        columns=["run_id", "terrain", "t_start_s", "t_end_s", "start_index"])
    meta["run_id"] = meta["run_id"].astype(object)
    return meta


class _RowArrays:
    """The per-row arrays of one :func:`cut_windows` call and the per-window rules on them.

    Every per-row conversion is elementwise, so a window's arrays are identical whatever rows
    surround it (offline table or online ring buffer).
    """

    def __init__(self, cols: "_Columns", robot: RobotSpec, spec: WindowSpec, channels: tuple[str, ...]):
        self.spec = spec
        N = self.N = robot.n_wheels
        n = cols.n
        self.t = cols.float("t_s")
        vx, vy = cols.float(EST_VX), cols.float(EST_VY)
        r = cols.float(EST_YAW_RATE)
        ax, ay = cols.float("ekf_ax_mps2"), cols.float("ekf_ay_mps2")
        if spec.remove_centripetal:
            ax, ay = ax - r * vy, ay + r * vx
        self.ax, self.ay = ax, ay
        self.speed = np.hypot(vx, vy)
        self.active = spec.active_rules
        self.channels = channels
        self.bad: dict[str, int] = {}  # channel -> candidate windows it made fail channel_valid
        # a share of ticks is never below 0: with min_steady_fraction <= 0 (``short``) the wheel-state
        # rule cannot reject a window, so the state columns are not read at all
        self.check_states = "wheel_state" in self.active and spec.min_steady_fraction > 0
        self.steady = np.ones((N, n), dtype=bool)
        # "dominant" mode: per wheel, one boolean row per moving state (the window keeps the
        # state that holds >= min_steady_fraction of its ticks)
        self.moving = np.zeros((len(MOVING_STATES), N, n), dtype=bool)
        if self.check_states:
            self._read_states(cols)
        self.steer = np.empty((N, n))
        for i in range(1, N + 1):
            name = f"ekf_steer{i}_rad" if cols.has(f"ekf_steer{i}_rad") else wheel_col("steer", i)
            self.steer[i - 1] = cols.float(name) if cols.has(name) else 0.0
        self.labelled = cols.has("terrain")
        if self.labelled:
            lab = cols.float("terrain")
            self.lab = np.where(np.isfinite(lab) & (lab >= 0), lab, np.nan)
        self._read_channels(cols, robot, channels)

    def _read_states(self, cols: "_Columns") -> None:
        for i in range(1, self.N + 1):
            col = f"state{i}"
            if cols.has(col):
                st = cols.text(col)
                self.steady[i - 1] = (st == STEADY_STATES[0]) | (st == STEADY_STATES[1])
                for k, name in enumerate(MOVING_STATES):
                    self.moving[k, i - 1] = st == name
            else:
                self.steady[i - 1] = False

    def _read_channels(self, cols: "_Columns", robot: RobotSpec, channels: tuple[str, ...]) -> None:
        plan = _channel_plan(channels, robot)  # ValueError: a channel names a missing wheel
        C, n = len(channels), cols.n
        self.C = C
        self.data = np.empty((C, n))
        self.valid = np.empty((C, n), dtype=bool)
        for k, (col, vcols, scale) in enumerate(plan):
            x = cols.float(col)
            if scale != 1.0:
                x = x * scale
            ok = np.isfinite(x)
            for vc in vcols:
                ok &= cols.bool(vc)
            self.data[k], self.valid[k] = x, ok

    def fails(self, s: int, T: int) -> tuple[list[str], np.ndarray]:
        """The rules the window of rows ``s .. s + T - 1`` fails (of the active ones) and its labels."""
        spec, e = self.spec, s + T
        fails = []
        dt = 1.0 / spec.rate_hz
        tw = self.t[s:e]
        span = tw[-1] - tw[0]
        if not (np.all(np.isfinite(tw)) and abs(span - (T - 1) * dt) <= 0.5 * dt):
            fails.append("time_gap")
        if self.check_states and self._wheel_state_fails(s, e):
            fails.append("wheel_state")
        sp = self.speed[s:e]
        sp = sp[np.isfinite(sp)]
        if sp.size == 0 or not sp.mean() >= spec.min_speed_mps:
            fails.append("speed")
        axw, ayw = self.ax[s:e], self.ay[s:e]
        axw, ayw = axw[np.isfinite(axw)], ayw[np.isfinite(ayw)]
        if (axw.size == 0 or ayw.size == 0 or not abs(axw.mean()) < spec.max_mean_abs_accel_mps2
                or not abs(ayw.mean()) < spec.max_mean_abs_accel_mps2):
            fails.append("acceleration")
        if self.N and np.any(_steer_std(self.steer[:, s:e]) >= spec.max_steer_std_rad):
            fails.append("steering")
        labels = _NO_LABELS
        if self.labelled:  # no label column (the serving path): nothing to check
            lw = self.lab[s:e]
            labels = np.unique(lw[np.isfinite(lw)])
            if labels.size > 1:
                if spec.label_at == "end":  # the terrain under the robot when the window ends
                    labels = lw[np.isfinite(lw)][-1:]
                else:
                    fails.append("terrain_label")
        vw = self.valid[:, s:e]
        self._all_valid = bool(vw.all())
        if self.C and not self._all_valid:
            low = vw.mean(axis=1) < spec.min_valid_fraction
            if low.any():
                fails.append("channel_valid")
                if "channel_valid" in self.active:  # which channels: the one rule that can name them
                    for k in np.flatnonzero(low):
                        self.bad[self.channels[k]] = self.bad.get(self.channels[k], 0) + 1
        if spec.rules is not None:
            fails = [f for f in fails if f in self.active]
        return fails, labels

    def _wheel_state_fails(self, s: int, e: int) -> bool:
        if self.spec.wheel_state_mode == "dominant":
            frac = self.moving[:, :, s:e].mean(axis=2).max(axis=0)  # (N,) share of each wheel's top state
            return bool(self.N and np.any(frac < self.spec.min_steady_fraction))
        return bool(np.any(self.steady[:, s:e].mean(axis=1) < self.spec.min_steady_fraction))

    def window(self, s: int, T: int) -> np.ndarray:
        """The window (C, T) of the rows :meth:`fails` last checked; invalid samples interpolated."""
        e = s + T
        if self._all_valid:  # nothing to fill: one copy of the window
            return self.data[:, s:e].copy()
        vw = self.valid[:, s:e]
        xw = np.empty((self.C, T))
        for k in range(self.C):
            xw[k] = _fill_invalid(self.data[k, s:e], vw[k])
        return xw


_NO_LABELS = np.zeros(0)
