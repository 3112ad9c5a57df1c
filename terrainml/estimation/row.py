"""The estimator (EST) row: what :meth:`OnlineEstimator.step` makes for one tick (contract 2).

An :class:`EstimatorRow` is immutable: its values in column order (a tuple) and a shared
:class:`RowLayout` naming them. The column names are the EST table's (:func:`terrainml.schema.est_columns`,
then the run-table columns passed through), so a row reads like the offline table's row: by
name (``row["slip1"]``, a read-only mapping), per wheel through the schema's names
(:meth:`EstimatorRow.wheels`), and as a whole in column order (:attr:`EstimatorRow.values`, what
the serving ring buffer copies without building a dict). A consumer that changes something makes
a new row (:meth:`EstimatorRow.with_flag`, :meth:`EstimatorRow.with_columns`).

A layout is made once per distinct column set (a sample's key layout changes rarely) and cached,
so a tick costs one tuple and one small object.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from operator import itemgetter
from typing import Any, Callable, Sequence

from terrainml.schema import EST_OK, est_wheel_col

__all__ = ["EstimatorRow", "RowLayout"]

#: most layouts :meth:`RowLayout.of` keeps (rows of a mapping-returning estimator); then it starts over
_MAX_LAYOUTS = 64


class RowLayout:
    """The column names of estimator rows, in order, and each one's position.

    One layout is shared by every row with the same columns; what is derived from it (the
    layout with more columns, per-wheel positions) is cached on it.

    Parameters
    ----------
    names : the column names, in order, each once.
    """

    __slots__ = ("names", "index", "_plus", "_wheels")
    _by_names: dict[tuple[str, ...], "RowLayout"] = {}

    def __init__(self, names: Sequence[str]):
        self.names: tuple[str, ...] = tuple(names)
        self.index: dict[str, int] = {name: j for j, name in enumerate(self.names)}
        if len(self.index) != len(self.names):
            raise ValueError("an estimator row names a column twice")
        self._plus: dict[tuple[str, ...], RowLayout] = {}
        self._wheels: dict[tuple[str, int], Callable[[tuple], Any] | None] = {}

    @classmethod
    def of(cls, names: Sequence[str]) -> "RowLayout":
        """The shared layout of these column names (made on first use)."""
        key = tuple(names)
        layout = cls._by_names.get(key)
        if layout is None:
            if len(cls._by_names) >= _MAX_LAYOUTS:
                cls._by_names.clear()
            layout = cls._by_names[key] = cls(key)
        return layout

    def plus(self, extra: tuple[str, ...]) -> "RowLayout":
        """This layout followed by the columns ``extra`` (none of them in it)."""
        out = self._plus.get(extra)
        if out is None:
            out = self._plus[extra] = RowLayout(self.names + extra)
        return out

    def wheel_getter(self, kind: str, n_wheels: int) -> Callable[[tuple], Any] | None:
        """A getter of the values of per-wheel column ``kind`` for wheels 1..N (None when a wheel's
        column is missing)."""
        key = (kind, n_wheels)
        if key not in self._wheels:
            pos = [self.index.get(est_wheel_col(kind, i)) for i in range(1, n_wheels + 1)]
            getter = None
            if None not in pos:
                getter = itemgetter(*pos) if n_wheels > 1 else (lambda v, j=pos[0]: (v[j],))
            self._wheels[key] = getter
        return self._wheels[key]


class EstimatorRow(Mapping):
    """One tick's EST row, immutable: ``t_s``, ``estimator_ok`` and the EST values by column name.

    Parameters
    ----------
    layout : the column names (:class:`RowLayout`).
    values : the values, one per column, in the layout's order: floats (SI units of the column's
        name), bools (flags), ints (``nis_dof``, ``terrain``), strs (wheel states, ``run_id``).
    """

    __slots__ = ("layout", "values")
    layout: RowLayout
    values: tuple[Any, ...]

    def __init__(self, layout: RowLayout, values: tuple[Any, ...]):
        object.__setattr__(self, "layout", layout)
        object.__setattr__(self, "values", values)

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError("an EstimatorRow is immutable: make a new one (with_flag, with_columns)")

    @classmethod
    def from_mapping(cls, row: Mapping[str, Any]) -> "EstimatorRow":
        """The typed row of a mapping of column names to values (an EstimatorRow as is)."""
        if type(row) is cls:
            return row  # type: ignore[return-value]
        return cls(RowLayout.of(tuple(row)), tuple(row.values()))

    # ------------------------------------------------------------------ read
    @property
    def t_s(self) -> float:
        """Tick time (s); NaN when the row has no ``t_s``."""
        j = self.layout.index.get("t_s")
        return math.nan if j is None else float(self.values[j])

    @property
    def estimator_ok(self) -> bool:
        """The estimator's health flag (``estimator_ok``); True for a row without one."""
        j = self.layout.index.get(EST_OK)
        return True if j is None else bool(self.values[j])

    def wheels(self, kind: str, n_wheels: int) -> tuple[Any, ...] | None:
        """The per-wheel column ``kind`` (``schema.EST_WHEEL_KINDS``: steer rad, slip -, state,
        v_long m/s) of wheels 1..N, or None if a wheel's column is missing."""
        getter = self.layout.wheel_getter(kind, n_wheels)
        return None if getter is None else getter(self.values)

    def __getitem__(self, name: str) -> Any:
        return self.values[self.layout.index[name]]

    def get(self, name: str, default: Any = None) -> Any:
        j = self.layout.index.get(name)
        return default if j is None else self.values[j]

    def __contains__(self, name: object) -> bool:
        return name in self.layout.index

    def __iter__(self) -> Iterator[str]:
        return iter(self.layout.names)

    def __len__(self) -> int:
        return len(self.values)

    def __repr__(self) -> str:
        return f"EstimatorRow({dict(zip(self.layout.names, self.values))!r})"

    # ------------------------------------------------------------------ new rows
    def with_flag(self, estimator_ok: bool) -> "EstimatorRow":
        """This row with ``estimator_ok`` set (added last when the row has none)."""
        j = self.layout.index.get(EST_OK)
        if j is None:
            return EstimatorRow(self.layout.plus((EST_OK,)), self.values + (estimator_ok,))
        v = self.values
        return EstimatorRow(self.layout, v[:j] + (estimator_ok,) + v[j + 1:])

    def with_columns(self, names: tuple[str, ...], values: tuple[Any, ...]) -> "EstimatorRow":
        """This row followed by the columns ``names`` (none of them in it) with ``values``."""
        if not names:
            return self
        return EstimatorRow(self.layout.plus(names), self.values + values)
