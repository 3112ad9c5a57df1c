"""Column ring buffer of the online predictor: the last window of estimator rows (design §11).

:class:`RingBuffer` keeps a fixed number of EST rows (one window length) in preallocated arrays
with O(1) append (a row's values copied in column order, no dict); :meth:`RingBuffer.snapshot`
copies them in time order on the tick path, and :meth:`RingBuffer.column_view` (a
:class:`SnapshotColumns`) hands the classification thread the columns in place, labels left out
(:func:`is_label`), without building a DataFrame.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from operator import itemgetter
from typing import Callable

import numpy as np
import pandas as pd

from terrainml.estimation.row import EstimatorRow, RowLayout

__all__ = ["RingBuffer", "SnapshotColumns", "is_label"]


#: the value of a numeric field a row lacks
_PAD = (math.nan,)


def is_label(name: str) -> bool:
    """Logged labels and simulator truth: never seen by the serving path."""
    return name in ("terrain", "run_id") or name.startswith("gt_")


class RingBuffer:
    """Fixed-capacity buffer of estimator rows (:class:`~terrainml.estimation.row.EstimatorRow`)
    with O(1) append.

    Numeric fields are kept in a preallocated float array, everything else (wheel states,
    run id) in an object array; the fields are the first row's. A row's values are copied in
    column order through a plan made once per row layout (a later row lacking a field gives NaN
    there, or None for a non-numeric one; fields the first row lacked are not kept).
    :meth:`frame` returns the rows in time order as a DataFrame, the same layout as the offline
    EST table.
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
        self._plans: dict[RowLayout, tuple[Callable[[tuple], tuple], bool, list[int]]] = {}

    def _init(self, row: EstimatorRow) -> None:
        num, obj = [], []
        for k, v in zip(row.layout.names, row.values):
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

    def _plan(self, layout: RowLayout) -> tuple[Callable[[tuple], tuple], bool, list[int]]:
        """How a row of ``layout`` fills a slot: a getter of its numeric values (in the order of
        the numeric fields), whether it needs the values padded with one NaN (a numeric field the
        layout lacks reads past the end), and the positions of the other fields (-1: missing)."""
        n = len(layout.names)
        pos = [layout.index.get(k, n) for k in self._num_keys]  # type: ignore[union-attr]
        padded = n in pos
        getter: Callable[[tuple], tuple]
        if len(pos) == 1:
            getter = lambda v, j=pos[0]: (v[j],)  # noqa: E731 - itemgetter of one gives a scalar
        elif pos:
            getter = itemgetter(*pos)
        else:
            getter = lambda v: ()  # noqa: E731
        plan = (getter, padded, [layout.index.get(k, -1) for k in self._obj_keys])
        self._plans[layout] = plan
        return plan

    def append(self, row: EstimatorRow) -> None:
        """Copy ``row``'s values into the next slot (the oldest row when full)."""
        if self._num_keys is None:
            self._init(row)
        getter, padded, obj_pos = self._plans.get(row.layout) or self._plan(row.layout)
        values = row.values
        i = self._i
        num = self._num
        nums = getter(values + _PAD if padded else values)
        try:
            num[i] = nums  # type: ignore[index]
        except (TypeError, ValueError, OverflowError):  # e.g. a str, or an int beyond float
            for j, v in enumerate(nums):
                try:
                    num[i, j] = v  # type: ignore[index]
                except (TypeError, ValueError, OverflowError):
                    num[i, j] = math.nan  # type: ignore[index]
        obj = self._obj
        for j, p in enumerate(obj_pos):
            obj[i, j] = values[p] if p >= 0 else None  # type: ignore[index]
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
