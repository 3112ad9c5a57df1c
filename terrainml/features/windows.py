"""Steady 2 s windows cut from an EST table (design §8), offline and online with one function.

:func:`cut_windows` serves both paths:

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

Raw windows (the CNN's input and the feature sets' input) hold the channels
``slip_1..N, current_1..N, vx, vy, r, imu_ax, imu_ay, imu_az`` as an array (C, T) per window,
T = 200 at 100 Hz. A robot without camera (``robot.camera is None``: slip not observable) gets
no slip channels; ``spec.channels`` restricts the set (e.g. wheel channels only when the IMU is
missing). Channel names travel with the windows. Invalid samples inside a kept window (at most
5%) are filled by linear interpolation over the window's valid samples (edge values held).

Channel sources and validity:

==============  =========================  ==================================================
channel         EST column                 valid when
==============  =========================  ==================================================
``slip_i``      ``slip{i}``                finite, ``wheels_valid``, ``cam_valid``, ``estimator_ok``
``current_i``   ``wheel{i}_current_a``     finite, ``current_valid``
``vx, vy, r``   ``ekf_vx_mps`` ...         finite, ``estimator_ok``
``imu_a*``      ``imu_a*_mps2``            finite, ``imu_valid``
==============  =========================  ==================================================

A missing ``*_valid`` / ``estimator_ok`` column counts as valid (finiteness still applies); a
missing data column makes its channel invalid everywhere.

Side channels of a skid-steer robot without camera or steering (design §8, BorealTC):
``imu_wx, imu_wy, imu_wz`` (``imu_{roll,pitch,yaw}_rate_radps``, ``imu_valid``),
``current_left/right`` (the current of the first left/right wheel, ``current_valid``) and
``speed_left/right_mps`` (that wheel's ``omega * R``, ``wheels_valid``); left is y > 0.

Named window specs (:data:`WINDOW_SPECS`, :func:`window_spec`; ``--windows NAME`` on the
command line), design §8:

``steady``  the rules above (default; the reference robot's training windows).
``chunks``  the BorealTC authors' fixed windows: 1.7 s windows inside non-overlapping 5 s chunks,
            kept when every sample of the chunk is valid and labelled alike; offline the chunk
            and class balancing are :mod:`terrainml.features.chunks`; online the latest 1.7 s
            window with every used channel valid. No motion rule: the terrain is read from
            vibration and motor load whatever the manoeuvre.
``state``   windows conditioned on the dynamic state: every wheel in one *moving* state
            (steady, traction or braking) for >= 90% of ticks, speed and steering rules, no
            acceleration rule, so accelerating and braking stretches give windows too.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields, replace
from functools import lru_cache
from typing import Any, Iterable, Sequence

import numpy as np
import pandas as pd

from terrainml.robot import RobotSpec

__all__ = ["WindowSpec", "Windows", "cut_windows", "RULES", "WINDOW_SPECS",
           "window_spec", "default_channels", "channel_source",
           "SIDE_CHANNEL_NAMES", "WHEEL_STATE_MODES", "channel_sensor_group", "is_side_channel_set",
           "channel_column", "side_wheels", "SENSOR_GROUPS"]

RULES: tuple[str, ...] = ("time_gap", "wheel_state", "speed", "acceleration", "steering",
                          "terrain_label", "channel_valid")
STEADY_STATES = ("steady", "idle")
BODY_CHANNELS = ("vx", "vy", "r")
IMU_CHANNELS = ("imu_ax", "imu_ay", "imu_az")
#: side channels of a camera-less skid-steer robot (design §8): IMU, then per-side current and speed
SIDE_CHANNEL_NAMES = IMU_CHANNELS + ("imu_wx", "imu_wy", "imu_wz", "current_left", "current_right",
                                     "speed_left_mps", "speed_right_mps")
_GYRO_COLUMNS = {"imu_wx": "imu_roll_rate_radps", "imu_wy": "imu_pitch_rate_radps",
                 "imu_wz": "imu_yaw_rate_radps"}
#: ``steady``: every wheel steady or idle; ``dominant``: every wheel in one moving state
WHEEL_STATE_MODES = ("steady", "dominant")
MOVING_STATES = ("steady", "traction", "braking")
#: sensor groups a window channel (and a model) may need: wheel speeds, motor currents, IMU, camera
SENSOR_GROUPS = ("wheels", "currents", "imu", "cam")
#: ``only``: a window with two terrain labels is rejected (``terrain_label``); ``end``: kept,
#: labelled with the terrain of its newest labelled row
LABEL_AT = ("only", "end")


@dataclass(frozen=True)
class WindowSpec:
    """Window length, hops and steady-rule thresholds (defaults: design §8).

    Attributes
    ----------
    window_s : float, window length in s (2.0).
    hop_s : float, offline hop in s (2.0: non-overlapping).
    online_hop_s : float, online hop in s (0.5).
    rate_hz : float, base rate of the EST table in Hz (100).
    min_steady_fraction : float, share of ticks each wheel must be steady or idle (0.9).
    min_speed_mps : float, minimum mean body speed in m/s (0.2).
    max_mean_abs_accel_mps2 : float, bound on |mean ax| and |mean ay| in m/s^2 (0.15).
    max_steer_std_rad : float, bound on each wheel's steering std in rad (0.05).
    min_valid_fraction : float, share of ticks each used channel must be valid (0.95).
    remove_centripetal : bool, test dv/dt (ax - r vy, ay + r vx) instead of the EKF's
        acceleration states (False: the design's literal rule).
    channels : tuple of str or None, channels to cut (None: all the robot has).
    label_at : str, ``only`` (a window with two terrain labels is rejected) or ``end`` (kept,
        labelled with the terrain of its newest labelled row; offline only, serving has no labels).
    name : str, the named spec this one was made from (:data:`WINDOW_SPECS`; "steady" by
        default). Recorded with datasets and model artifacts, so the predictor cuts exactly
        what the model was trained on.
    """

    window_s: float = 2.0
    hop_s: float = 2.0
    online_hop_s: float = 0.5
    rate_hz: float = 100.0
    min_steady_fraction: float = 0.9
    min_speed_mps: float = 0.2
    max_mean_abs_accel_mps2: float = 0.15
    max_steer_std_rad: float = 0.05
    min_valid_fraction: float = 0.95
    remove_centripetal: bool = False
    channels: tuple[str, ...] | None = None
    name: str = "steady"
    rules: tuple[str, ...] | None = None
    wheel_state_mode: str = "steady"
    chunk_s: float | None = None
    windows_per_chunk: int = 11
    homogeneous: bool = True
    label_at: str = "only"

    def __post_init__(self) -> None:
        for name in ("window_s", "hop_s", "online_hop_s", "rate_hz"):
            if not float(getattr(self, name)) > 0:
                raise ValueError(f"WindowSpec.{name} must be > 0, got {getattr(self, name)!r}")
        if self.n_samples < 2:
            raise ValueError("WindowSpec: a window needs at least 2 samples")
        if self.channels is not None:
            object.__setattr__(self, "channels", tuple(str(c) for c in self.channels))
            for c in self.channels:
                channel_source(c)  # ValueError naming an unknown channel
        if self.rules is not None:
            object.__setattr__(self, "rules", tuple(str(r) for r in self.rules))
            unknown = [r for r in self.rules if r not in RULES]
            if unknown:
                raise ValueError(f"WindowSpec.rules: unknown rule(s) {unknown}; known {list(RULES)}")
        if self.wheel_state_mode not in WHEEL_STATE_MODES:
            raise ValueError(f"WindowSpec.wheel_state_mode must be one of {WHEEL_STATE_MODES}, "
                             f"got {self.wheel_state_mode!r}")
        if self.chunk_s is not None and not float(self.chunk_s) >= self.window_s:
            raise ValueError(f"WindowSpec.chunk_s ({self.chunk_s}) must be >= window_s ({self.window_s})")
        if int(self.windows_per_chunk) < 1:
            raise ValueError("WindowSpec.windows_per_chunk must be >= 1")
        if self.label_at not in LABEL_AT:
            raise ValueError(f"WindowSpec.label_at must be one of {LABEL_AT}, got {self.label_at!r}")

    @property
    def active_rules(self) -> tuple[str, ...]:
        """The rules this spec applies (all of :data:`RULES` unless ``rules`` names a subset)."""
        return RULES if self.rules is None else self.rules

    @property
    def n_samples(self) -> int:
        """Samples per window T = round(window_s * rate_hz)."""
        return int(round(self.window_s * self.rate_hz))

    def hop_samples(self, online: bool = False) -> int:
        """Hop in samples (offline or online)."""
        return max(1, int(round((self.online_hop_s if online else self.hop_s) * self.rate_hz)))

    def channels_for(self, robot: RobotSpec, sensors: Sequence[str] | None = None) -> tuple[str, ...]:
        """The window channels for ``robot``, restricted to the sensor groups ``sensors``.

        ``channels`` wins when given. A chunked spec (``chunk_s``, the ``chunks`` spec) takes the
        side channels of a camera-less robot (design §8), the other specs the canonical channels
        (:func:`default_channels`). ``sensors`` (None: all) keeps only the channels of the groups
        listed (of :data:`SENSOR_GROUPS`; the estimator's and the wheels' always). ValueError names
        an unknown group, or says that no channel is left.
        """
        if sensors is not None:
            unknown = [g for g in sensors if g not in SENSOR_GROUPS]
            if unknown:
                raise ValueError(f"unknown sensor group(s) {unknown}; expected some of {list(SENSOR_GROUPS)}")
        if self.channels is not None:
            chans = tuple(self.channels)
        elif self.chunk_s is not None:
            chans = SIDE_CHANNEL_NAMES
        else:
            chans = default_channels(robot)
        if sensors is None:
            return chans
        keep = set(sensors) | {"estimator", "wheels"}
        out = tuple(c for c in chans if channel_sensor_group(c) in keep)
        if not out:
            raise ValueError(f"no window channel left for sensors {list(sensors)} (channels {list(chans)})")
        return out

    def resolve(self, robot: RobotSpec, sensors: Sequence[str] | None = None) -> "WindowSpec":
        """This spec as a dataset of ``robot`` records it: what every step below the edge takes.

        With ``sensors`` the channels are :meth:`channels_for` those groups; a chunked spec
        without channels gets its side channels. Otherwise ``channels`` stays None, meaning the
        robot's canonical channels (so specs, datasets and artifacts keep their recorded form).
        """
        if sensors is not None or (self.chunk_s is not None and self.channels is None):
            return replace(self, channels=self.channels_for(robot, sensors))
        return self

    def to_dict(self) -> dict:
        d = asdict(self)
        d["channels"] = None if self.channels is None else list(self.channels)
        d["rules"] = None if self.rules is None else list(self.rules)
        if d["label_at"] == "only":  # the default is left out: specs, caches and artifacts made
            del d["label_at"]        # before the field existed keep their keys
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "WindowSpec":
        known = {f.name for f in fields(cls)}
        unknown = set(d) - known
        if unknown:
            raise ValueError(f"WindowSpec: unknown field(s) {sorted(unknown)}")
        d = dict(d)
        if d.get("channels") is not None:
            d["channels"] = tuple(d["channels"])
        if d.get("rules") is not None:
            d["rules"] = tuple(d["rules"])
        return cls(**d)

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True)


# ------------------------------------------------------------------------------ named specs
#: Named window specs (design §8): field overrides of :class:`WindowSpec`'s defaults.
#: ``steady`` is today's rules (2 s steady windows, thesis §8.1). ``short`` is
#: made for stop-and-go: 1 s windows in any wheel state (traction phases included, so the
#: features see the soil while the robot accelerates), kept when the robot moves (mean body
#: speed >= 0.3 m/s, i.e. >= 0.3 m travelled) and its net acceleration is moderate; online a
#: new window every 0.1 s; offline a window across a terrain change is kept with the terrain at
#: its end (``label_at="end"``: trained on such windows the classifier names one of the two real
#: classes where a 1 s window straddles them, not a third one). A legacy artifact without a name
#: is ``steady``.
WINDOW_SPECS: dict[str, dict[str, Any]] = {
    "steady": {},
    "short": {"window_s": 1.0, "hop_s": 0.5, "online_hop_s": 0.1, "min_steady_fraction": 0.0,
              "min_speed_mps": 0.3, "max_mean_abs_accel_mps2": 0.5, "label_at": "end"},
    # the BorealTC authors' fixed windows, and windows conditioned on the dynamic state
    "chunks": {"window_s": 1.7, "hop_s": 1.7, "online_hop_s": 0.5, "chunk_s": 5.0,
               "windows_per_chunk": 11, "homogeneous": True, "min_valid_fraction": 1.0,
               "rules": ("time_gap", "terrain_label", "channel_valid")},
    "state": {"wheel_state_mode": "dominant",
              "rules": ("time_gap", "wheel_state", "speed", "steering", "terrain_label", "channel_valid")},
}


def window_spec(name: str = "steady", **overrides: Any) -> WindowSpec:
    """The named spec ``name`` (:data:`WINDOW_SPECS`) with field ``overrides``.

    Raises ValueError naming the known specs for an unknown name.
    """
    if name not in WINDOW_SPECS:
        raise ValueError(f"unknown window spec {name!r}; expected one of {sorted(WINDOW_SPECS)}")
    return replace(WindowSpec(name=name, **WINDOW_SPECS[name]), **overrides)


# ------------------------------------------------------------------------------ channels
def channel_sensor_group(channel: str) -> str:
    """Sensor group a channel needs: ``wheels``, ``currents``, ``imu``, ``cam`` or ``estimator``."""
    if channel.startswith("slip_"):
        return "cam"
    if channel.startswith("current_"):
        return "currents"
    if channel.startswith("speed_"):
        return "wheels"
    if channel.startswith("imu_"):
        return "imu"
    return "estimator"


def is_side_channel_set(channels: Sequence[str]) -> bool:
    """True when every channel is a side channel (the side-channel feature family applies)."""
    return bool(channels) and all(c in SIDE_CHANNEL_NAMES for c in channels)


def side_wheels(robot: RobotSpec) -> tuple[int, int]:
    """1-based indices of the first left (y > 0) and first right (y < 0) wheel (1, 2 if unclear)."""
    left = next((i for i, w in enumerate(robot.wheels, 1) if w.y_m > 0), 1)
    right = next((i for i, w in enumerate(robot.wheels, 1) if w.y_m < 0), min(2, robot.n_wheels))
    return left, right


def default_channels(robot: RobotSpec) -> tuple[str, ...]:
    """Raw-window channels for a robot: slips (only with a camera), currents, body, IMU."""
    n = robot.n_wheels
    slips = tuple(f"slip_{i}" for i in range(1, n + 1)) if robot.camera is not None else ()
    currents = tuple(f"current_{i}" for i in range(1, n + 1))
    return slips + currents + BODY_CHANNELS + IMU_CHANNELS


def channel_source(channel: str) -> tuple[str, tuple[str, ...]]:
    """EST column and validity columns of a channel, e.g. ``("slip1", ("wheels_valid", ...))``."""
    if channel.startswith("slip_"):
        i = int(channel[5:])
        return f"slip{i}", ("wheels_valid", "cam_valid", "estimator_ok")
    if channel.startswith("current_") and channel[8:].isdigit():
        i = int(channel[8:])
        return f"wheel{i}_current_a", ("current_valid",)
    body = {"vx": "ekf_vx_mps", "vy": "ekf_vy_mps", "r": "ekf_yaw_rate_radps"}
    if channel in body:
        return body[channel], ("estimator_ok",)
    if channel in IMU_CHANNELS:
        return f"{channel}_mps2", ("imu_valid",)
    if channel in _GYRO_COLUMNS:
        return _GYRO_COLUMNS[channel], ("imu_valid",)
    # side channels: the wheel index is resolved per robot in cut_windows (side_wheels); the
    # Husky convention (left wheel 1, right wheel 2) is the default
    sides = {"current_left": ("wheel1_current_a", "current_valid"),
             "current_right": ("wheel2_current_a", "current_valid"),
             "speed_left_mps": ("wheel1_omega_radps", "wheels_valid"),
             "speed_right_mps": ("wheel2_omega_radps", "wheels_valid")}
    if channel in sides:
        col, v = sides[channel]
        return col, (v,)
    raise ValueError(f"unknown window channel {channel!r}; expected slip_i, current_i, vx, vy, r, "
                     f"imu_ax, imu_ay, imu_az or a side channel {list(SIDE_CHANNEL_NAMES[3:])}")


def channel_column(channel: str, robot: RobotSpec) -> tuple[str, tuple[str, ...], float]:
    """EST/run-table column, validity columns and scale of a channel for ``robot``.

    Side channels take the robot's first left/right wheel; ``speed_*_mps`` scales the wheel's
    rad/s by the wheel radius (m), every other channel has scale 1.
    """
    col, vcols = channel_source(channel)
    if channel.endswith(("_left", "_left_mps", "_right", "_right_mps")) and channel not in IMU_CHANNELS:
        left, right = side_wheels(robot)
        i = left if "_left" in channel else right
        col = f"wheel{i}_current_a" if channel.startswith("current_") else f"wheel{i}_omega_radps"
        if channel.startswith("speed_"):
            return col, vcols, float(robot.wheel_radius_m)
    return col, vcols, 1.0


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


# ------------------------------------------------------------------------------ container
@dataclass
class Windows:
    """A stack of raw windows with their metadata.

    Attributes
    ----------
    X : ndarray (n_windows, n_channels, n_samples), float64, SI units of the channels.
    channels : tuple of str, channel names (length n_channels).
    meta : DataFrame (n_windows rows): ``run_id`` (str), ``terrain`` (int, -1 unlabelled),
        ``t_start_s``, ``t_end_s`` (s), ``start_index`` (row of the EST table).
    rate_hz : float, sample rate of the windows.
    """

    X: np.ndarray
    channels: tuple[str, ...]
    meta: pd.DataFrame
    rate_hz: float = 100.0
    attrs: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.X.shape[0])

    def __array__(self, dtype=None, copy=None):
        return self.X if dtype is None else self.X.astype(dtype)

    @property
    def y(self) -> np.ndarray:
        """Terrain labels (int), shape (n_windows,)."""
        return self.meta["terrain"].to_numpy(dtype=np.int64)

    @property
    def groups(self) -> np.ndarray:
        """Run ids (CV groups), shape (n_windows,)."""
        return self.meta["run_id"].astype(str).to_numpy(dtype=object)

    def subset(self, idx) -> "Windows":
        idx = np.asarray(idx)
        return Windows(self.X[idx], self.channels, self.meta.iloc[idx].reset_index(drop=True),
                       self.rate_hz, dict(self.attrs))

    def select_channels(self, channels: Sequence[str]) -> "Windows":
        """The same windows with channels reordered/selected by name (KeyError names the channel)."""
        pos = []
        for c in channels:
            if c not in self.channels:
                raise KeyError(f"window channel {c!r} not present (have {list(self.channels)})")
            pos.append(self.channels.index(c))
        return Windows(self.X[:, pos, :], tuple(channels), self.meta, self.rate_hz, dict(self.attrs))

    @staticmethod
    def concat(items: Iterable["Windows"], channels: Sequence[str] | None = None,
               n_samples: int | None = None, rate_hz: float = 100.0) -> "Windows":
        items = [w for w in items if w is not None]
        nonempty = [w for w in items if len(w)]
        if channels is None:
            channels = items[0].channels if items else ()
        channels = tuple(channels)
        for w in nonempty:
            if tuple(w.channels) != channels:
                raise ValueError(f"cannot concatenate windows with channels {list(w.channels)} "
                                 f"and {list(channels)}")
        if nonempty:
            X = np.concatenate([w.X for w in nonempty], axis=0)
            meta = pd.concat([w.meta for w in nonempty], ignore_index=True)
            rate_hz = nonempty[0].rate_hz
        else:
            T = n_samples or 0
            X = np.zeros((0, len(channels), T))
            meta = _empty_meta()
        return Windows(X, channels, meta, rate_hz)


def _empty_meta() -> pd.DataFrame:
    return pd.DataFrame({"run_id": pd.Series([], dtype=object), "terrain": pd.Series([], dtype=np.int64),
                         "t_start_s": pd.Series([], dtype=float), "t_end_s": pd.Series([], dtype=float),
                         "start_index": pd.Series([], dtype=np.int64)})


# ------------------------------------------------------------------------------ cutting
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


def cut_windows(est: pd.DataFrame | Mapping[str, np.ndarray], robot: RobotSpec,
                spec: WindowSpec | None = None, online: bool = False,
                run_id: str | None = None, *, with_meta: bool = True) -> tuple[Windows, dict[str, int]]:
    """Cut steady windows from an EST table (contract 2) or a ring buffer of EST rows.

    Parameters
    ----------
    est : DataFrame (n_rows, ...), EST table rows in time order at ``spec.rate_hz``; or a mapping
        of column name -> array (n_rows,) (the predictor's ring buffer, no DataFrame built on
        the serving path). Both go through the same per-row conversions and rules.
    robot : RobotSpec (resolved by the caller); gives N and the channel set.
    spec : WindowSpec (None: defaults).
    online : bool, False: windows from row 0 every ``hop_s``; True: windows ending at the last
        row every ``online_hop_s`` backwards (a one-window buffer gives the latest window).
    run_id : str, run id for the metadata when the table has no ``run_id`` column.
    with_meta : bool, False: ``Windows.meta`` is None (the serving path needs only X; building the
        metadata DataFrame cost more than the rules, features and SVM together).

    Returns
    -------
    windows : Windows, the kept windows (X shape (n_kept, C, T)).
    counts : dict, ``n_windows`` (candidates), ``n_kept``, ``n_rejected`` and per rule of
        :data:`RULES` the number of candidate windows that rule rejected; ``invalid_channels``:
        {channel: windows rejected by ``channel_valid`` because that channel was valid on too
        few ticks} (the serving warning names them).
    """
    spec = spec or WindowSpec()
    channels = spec.channels_for(robot)
    cols = _Columns(est)
    n = cols.n
    T = spec.n_samples
    starts = _window_starts(n, T, spec.hop_samples(online), online)
    counts: dict[str, Any] = {"n_windows": int(len(starts)), "n_kept": 0, "n_rejected": 0}
    counts.update({r: 0 for r in RULES})
    counts["invalid_channels"] = {}
    C = len(channels)
    if len(starts) == 0:
        return Windows(np.zeros((0, C, T)), channels, _empty_meta() if with_meta else None,
                       spec.rate_hz), counts
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
    if not with_meta:
        X = np.stack(X_kept) if X_kept else np.zeros((0, C, T))
        return Windows(X, channels, None, spec.rate_hz), counts  # type: ignore[arg-type]
    if not X_kept:
        return Windows(np.zeros((0, C, T)), channels, _empty_meta(), spec.rate_hz), counts
    return Windows(np.stack(X_kept), channels, _window_meta(cols, meta_rows, run_id), spec.rate_hz), counts


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
        vx, vy = cols.float("ekf_vx_mps"), cols.float("ekf_vy_mps")
        r = cols.float("ekf_yaw_rate_radps")
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
            name = f"ekf_steer{i}_rad" if cols.has(f"ekf_steer{i}_rad") else f"wheel{i}_steer_rad"
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
