"""Column ring buffer of the online predictor: the last window of estimator rows (design §11).

:class:`RingBuffer` keeps a fixed number of EST rows (one window length) in preallocated arrays
with O(1) append; :meth:`RingBuffer.snapshot` copies them in time order on the tick path, and
:meth:`RingBuffer.column_view` (a :class:`SnapshotColumns`) hands the classification thread the
columns in place, labels left out (:func:`is_label`), without building a DataFrame.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Callable

import numpy as np
import pandas as pd

__all__ = ["RingBuffer", "SnapshotColumns", "is_label"]


def is_label(name: str) -> bool:
    """Logged labels and simulator truth: never seen by the serving path."""
    return name in ("terrain", "run_id") or name.startswith("gt_")


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

    def snapshot(self, last: int | None = None) -> tuple[np.ndarray, np.ndarray] | None:
        """Copy of the rows in time order (two arrays; tens of microseconds), or None if empty.

        ``last``: only the newest ``last`` rows (a window shorter than the buffer: a sensor
        member's, when the members' windows differ in length).

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
        if last is not None and last < len(order):
            order = order[len(order) - last:]
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
