"""The window container: a stack of raw windows (C, T) with their metadata (design §8).

Windows are cut by :func:`cut_windows` (rules: :mod:`terrainml.features.cutting`) under a
:class:`terrainml.features.window_spec.WindowSpec`, from the channels of
:mod:`terrainml.features.channels`; those names are importable from here too.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from collections.abc import Mapping
from typing import Iterable, Sequence

import numpy as np
import pandas as pd

from terrainml.features.cutting import cut_window_arrays, empty_window_meta
from terrainml.features.channels import (BODY_CHANNELS as BODY_CHANNELS, IMU_CHANNELS as IMU_CHANNELS,
                                         SENSOR_GROUPS as SENSOR_GROUPS,
                                         SIDE_CHANNEL_NAMES as SIDE_CHANNEL_NAMES,
                                         channel_column as channel_column,
                                         channel_sensor_group as channel_sensor_group,
                                         channel_source as channel_source, default_channels as default_channels,
                                         groups_read as groups_read,
                                         is_side_channel_set as is_side_channel_set, side_wheels as side_wheels)
from terrainml.features.window_spec import (LABEL_AT as LABEL_AT, MOVING_STATES as MOVING_STATES, RULES as RULES,
                                            STEADY_STATES as STEADY_STATES, WHEEL_STATE_MODES as WHEEL_STATE_MODES,
                                            WINDOW_SPECS as WINDOW_SPECS, WindowSpec as WindowSpec,
                                            window_spec as window_spec)
from terrainml.robot import RobotSpec

__all__ = ["WindowSpec", "Windows", "cut_windows", "RULES", "WINDOW_SPECS",
           "window_spec", "default_channels", "channel_source",
           "SIDE_CHANNEL_NAMES", "WHEEL_STATE_MODES", "channel_sensor_group", "is_side_channel_set",
           "channel_column", "side_wheels", "SENSOR_GROUPS", "groups_read"]


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
            meta = empty_window_meta()
        return Windows(X, channels, meta, rate_hz)


def cut_windows(est: pd.DataFrame | Mapping[str, np.ndarray], robot: RobotSpec,
                spec: WindowSpec | None = None, online: bool = False,
                run_id: str | None = None, *, with_meta: bool = True) -> tuple[Windows, dict[str, int]]:
    """Cut steady windows from an EST table (contract 2) or a ring buffer of EST rows
    (rules: :mod:`terrainml.features.cutting`).

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
    X, channels, meta, counts = cut_window_arrays(est, robot, spec, online, run_id, with_meta=with_meta)
    return Windows(X, channels, meta, spec.rate_hz), counts  # type: ignore[arg-type]  # meta None: with_meta False
