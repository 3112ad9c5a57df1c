"""The window spec: window length, hops and steady-rule thresholds, and the named specs (design §8).

Named window specs (:data:`WINDOW_SPECS`, :func:`window_spec`; ``--windows NAME`` on the
command line):

``steady``  the steady rules of :mod:`terrainml.features.cutting` (default; the reference robot's
            training windows).
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
from dataclasses import asdict, dataclass, fields, replace
from typing import Any, Sequence

from terrainml.features.channels import (
    SENSOR_GROUPS,
    SIDE_CHANNEL_NAMES,
    channel_sensor_group,
    channel_source,
    default_channels,
    groups_read,
)
from terrainml.features.window_presets import WINDOW_SPECS
from terrainml.robot import RobotSpec
from terrainml.schema import MOVING_WHEEL_STATES

__all__ = ["RULES", "STEADY_STATES", "WHEEL_STATE_MODES", "MOVING_STATES", "LABEL_AT", "WindowSpec",
           "WINDOW_SPECS", "window_spec"]

RULES: tuple[str, ...] = ("time_gap", "wheel_state", "speed", "acceleration", "steering",
                          "terrain_label", "channel_valid")
STEADY_STATES = ("steady", "idle")
#: ``steady``: every wheel steady or idle; ``dominant``: every wheel in one moving state
WHEEL_STATE_MODES = ("steady", "dominant")
MOVING_STATES = MOVING_WHEEL_STATES
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
        keep = groups_read(sensors, robot)
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


def window_spec(name: str = "steady", **overrides: Any) -> WindowSpec:
    """The named spec ``name`` (:data:`WINDOW_SPECS`) with field ``overrides``.

    Raises ValueError naming the known specs for an unknown name.
    """
    if name not in WINDOW_SPECS:
        raise ValueError(f"unknown window spec {name!r}; expected one of {sorted(WINDOW_SPECS)}")
    return replace(WindowSpec(name=name, **WINDOW_SPECS[name]), **overrides)
