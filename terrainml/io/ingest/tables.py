"""The tabular path of the ingest engine: CSV and Parquet files -> signals -> run table (design §5).

One run is one or several table files. Each file has a time column (scaled to seconds) and
*bindings* from its columns to canonical columns: a plain rename (a topic map's ``columns``) or,
from a dataset spec (:mod:`terrainml.io.ingest.dataset_spec`), a unit scale (``canonical = scale * cell +
offset``), a fan-out (one side's speed given to two wheels: several canonical columns bound to one
file column) and label names (text labels looked up by name; an unknown one is an error naming
the file, the column and the value).

Cell by cell (:mod:`terrainml.io.ingest.cells`): an empty/null cell is no sample; a bad cell
(unparseable, non-finite, wrongly typed) is counted and makes its sensor group invalid at that
row; a row the table flags invalid (``{group}_valid`` false) stays invalid. Both are kept as NaN
samples, so nothing is interpolated or held across them. Every file's columns become
:class:`~terrainml.io.ingest.signals.Signal` s at the file's own stamps, and one
:func:`~terrainml.io.ingest.signals.assemble` resamples them all onto the base grid -- the same
resampling, gap rule and label holding as the log path of :mod:`terrainml.io.ingest.logs`.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq

from terrainml.io import topics
from terrainml.io.ingest.cells import Cells, arrow_cells, series_cells
from terrainml.io.ingest.ingest_report import IngestReport
from terrainml.io.ingest.signals import PREVIOUS_COLUMNS, Signal, assemble
from terrainml.io.ingest.resample import clean_times, gap_threshold_s
from terrainml.robot import RobotSpec, check_wheel_count
from terrainml.schema import VALID_GROUPS, column_map, valid_column, wheel_col

_WHEEL_COLUMN = re.compile(r"^wheel(\d+)_(omega_radps|steer_rad|current_a)$")
SPANS = ("overlap", "union", "first")   # the time a multi-file run's grid covers (tables_to_run)


@dataclass(frozen=True)
class Binding:
    """One canonical column fed by a file column: ``canonical = scale * cell + offset``."""

    source: str                     # column name in the file (exact)
    scale: float = 1.0
    offset: float = 0.0
    method: str | None = None       # resample override: linear | previous (None: by column name)


@dataclass
class TableFile:
    """One CSV/Parquet file of a run and how its columns reach the canonical table.

    ``bindings`` maps canonical column -> :class:`Binding`; with ``pass_through`` the file's
    columns that already have canonical names (and are not bound) are read as they are.
    ``label_names``: the ``terrain`` cells are names (text, or numbers read as text) and the
    class id is the index in this list. ``gap_periods``: gap threshold in source periods,
    ``gap_periods * max(base period, median period)``.
    """

    path: Path
    fmt: str                                               # csv | parquet
    role: str = "<table>"                                  # its key in the report's per-topic counts
    time_column: str = "t_s"
    time_scale: float = 1.0
    bindings: dict[str, Binding] = field(default_factory=dict)
    pass_through: bool = True
    gap_periods: float = 2.0
    label_names: list[str] | None = None
    unlabelled: tuple[str, ...] = ("-1",)                   # label texts meaning "no label"
    name_by_source: bool = False                           # warnings name the file's column


class TableError(ValueError):
    """A table cannot be read as the spec says (the message names the file and column)."""


def read_table(path: Path, fmt: str, columns: list[str] | None = None):
    """A CSV (pandas, only empty cells as NA) or Parquet (Arrow) file: ``(DataFrame, None)`` or
    ``(None, pyarrow.Table)``."""
    if fmt == "csv":
        return pd.read_csv(path, keep_default_na=False, na_values=[""], usecols=columns), None
    return None, pq.read_table(path, columns=columns)


def table_header(path: Path, fmt: str) -> list[str]:
    """Column names of a CSV or Parquet file (reads the header only)."""
    if fmt == "csv":
        return [str(c) for c in pd.read_csv(path, nrows=0).columns]
    return list(pq.read_schema(path).names)


class _TableColumns:
    """The columns of one table file under their canonical names, read cell by cell."""

    def __init__(self, tf: TableFile):
        self.df, self.arrow = read_table(tf.path, tf.fmt)
        names = list(self.df.columns) if self.df is not None else self.arrow.column_names
        self.tf = tf
        bound = {b.source for b in tf.bindings.values()}
        self.source: dict[str, Binding] = {}     # canonical -> binding
        if tf.pass_through:
            self.source.update({n: Binding(n) for n in names if n not in bound})
        for canon, b in tf.bindings.items():
            if b.source in names:
                self.source[canon] = b
        if tf.time_column in names:
            self.source.setdefault(tf.time_column, Binding(tf.time_column))
        self._raw: dict[tuple[str, bool], Cells] = {}

    @property
    def names(self) -> list[str]:
        return list(self.source)

    def _source_cells(self, src: str, boolean: bool) -> Cells:
        key = (src, boolean)
        if key not in self._raw:
            self._raw[key] = arrow_cells(self.arrow[src], boolean=boolean) if self.arrow is not None \
                else series_cells(self.df[src], boolean=boolean)
        return self._raw[key]

    def cells(self, name: str, boolean: bool = False) -> Cells:
        b = self.source[name]
        c = self._source_cells(b.source, boolean)
        if b.scale == 1.0 and b.offset == 0.0:
            return c
        return replace(c, values=c.values * b.scale + b.offset)

    def raw(self, name: str) -> pd.Series:
        src = self.source[name].source
        return self.arrow[src].to_pandas() if self.arrow is not None else self.df[src]

    def label(self, name: str) -> str:
        """How warnings name a canonical column: the file's column (spec) or the canonical one."""
        return self.source[name].source if self.tf.name_by_source else name


def _label_text(x) -> str:
    """A label cell as text: numbers without a fractional part as integers (3.0 -> '3')."""
    if isinstance(x, (float, np.floating)) and np.isfinite(x) and float(x).is_integer():
        return str(int(x))
    return str(x).strip()


def label_values(tf: TableFile, column: str) -> list[str]:
    """The distinct label texts of a file's label column (empty cells and ``unlabelled`` left out)."""
    df, tbl = read_table(tf.path, tf.fmt, [column])
    s = df[column] if df is not None else tbl[column].to_pandas()
    texts = {_label_text(x) for x in s.dropna()}
    return sorted(t for t in texts if t and t not in tf.unlabelled)


def _label_cells(series: pd.Series, tf: TableFile, column: str) -> Cells:
    """Label cells (names) as class ids; an unknown name raises, naming file, column and value."""
    names = {n: i for i, n in enumerate(tf.label_names or [])}
    missing = series.isna().to_numpy(bool).copy()
    text = np.array(["" if m else _label_text(x) for x, m in zip(series.to_numpy(dtype=object), missing)],
                    dtype=object)
    missing |= text == ""
    values = np.full(len(text), np.nan)
    for t in np.unique(text[~missing]):
        if t in tf.unlabelled:
            values[text == t] = -1.0
        elif t in names:
            values[text == t] = names[t]
        else:
            raise TableError(f"{tf.path}: column '{column}': label {t!r} is not one of the label names "
                             f"{list(names)} (add it to the spec's label names)")
    no = np.zeros(len(text), bool)
    return Cells(np.where(missing, np.nan, values), missing, no, {})


def _table_wheels(names: list[str]) -> int:
    """Wheels a table has: the largest ``i`` of its ``wheel{i}_omega_radps/steer_rad/current_a``."""
    return max([int(m.group(1)) for m in map(_WHEEL_COLUMN.match, names) if m] + [0])


def _count_bad(path: Path, col: str, counts: dict[str, int], group: str, rep: IngestReport) -> None:
    if counts:
        rep.bad_cells[col] = counts
        what = ", ".join(f"{n} {k.replace('_', '-')}" for k, n in counts.items())
        rep.warnings.append(f"{path}: column '{col}': {sum(counts.values())} bad cell(s) ({what}); "
                            + (f"group {group} invalid at those rows" if group in VALID_GROUPS
                               else "value missing at those rows"))


@dataclass
class FileSignals:
    """One file's canonical columns at its own stamps (``t_s`` absolute, seconds)."""

    t_first_s: float
    t_last_s: float
    signals: list[Signal]
    columns: list[str]
    run_id: str | None = None


@dataclass
class _Rows:
    """The usable rows of one table file in time order (repeated stamps kept)."""

    t_s: np.ndarray        # (n,) stamps (s, the file's time scaled)
    index: np.ndarray      # (n,) their row numbers in the file
    n_file: int            # rows in the file

    def in_file(self, kept: np.ndarray) -> np.ndarray:
        """(n_file,) bool: the file rows of the kept rows (``kept``: (n,) bool)."""
        m = np.zeros(self.n_file, bool)
        m[self.index[kept]] = True
        return m


def _open_columns(tf: TableFile, robot: RobotSpec, rep: IngestReport) -> _TableColumns | None:
    """The file's columns, its time column checked and its wheel count checked against the robot."""
    try:
        cols = _TableColumns(tf)
    except Exception as exc:  # noqa: BLE001 - parser errors of several types
        rep.errors.append(f"{tf.path}: not a readable {tf.fmt.upper()} file ({exc})")
        return None
    if tf.time_column not in cols.source:
        rep.errors.append(f"{tf.path}: missing time column '{tf.time_column}' (give a topic map with time_column "
                          "and columns to map your file's names)")
        return None
    n_in_table = _table_wheels(cols.names)
    if n_in_table:
        check_wheel_count(robot, n_in_table, tf.path)
    return cols


def _time_rows(tf: TableFile, cols: _TableColumns, rep: IngestReport) -> _Rows | None:
    """Rows with a finite time, in time order; the file's counts into the report."""
    path, tcol = tf.path, tf.time_column
    tc = cols.cells(tcol)
    _count_bad(path, cols.label(tcol), tc.counts(), "time", rep)
    t = tc.values * float(tf.time_scale)
    fin = np.isfinite(t)
    if (~fin).any():
        rep.warnings.append(f"{path}: column '{cols.label(tcol)}': {int((~fin).sum())} row(s) without a "
                            "finite time dropped")
    _, ooo, dup = clean_times(t[fin])
    # rows in time order, repeated stamps kept: in a sparse multi-rate table a slow channel's row
    # may share its stamp with a fast channel's row; each column keeps its first sample per stamp
    rows = np.flatnonzero(fin)[np.argsort(t[fin], kind="stable")]
    rep.topics[tf.role] = {"type": tf.fmt, "mapped": True, "read": len(t), "decoded": len(rows) - dup, "corrupt": 0,
                           "skipped": int((~fin).sum()), "out_of_order": ooo, "duplicates": dup, "non_finite": 0}
    if ooo or dup:
        rep.warnings.append(f"{path}: column '{cols.label(tcol)}': {ooo} out-of-order and {dup} duplicate "
                            "time(s) (sorted, duplicates dropped)")
    if len(rows) == 0:
        rep.errors.append(f"{path}: no rows")
        return None
    return _Rows(t[rows], rows, len(tc.values))


def _single_run_id(cols: _TableColumns, r: _Rows) -> str | None:
    """The table's ``run_id`` when its rows hold a single one."""
    if "run_id" not in cols.names:
        return None
    run_ids = cols.raw("run_id").iloc[r.index]
    return str(run_ids.iloc[0]) if run_ids.nunique() == 1 else None


def _flagged_rows(tf: TableFile, cols: _TableColumns, r: _Rows, rep: IngestReport) -> dict[str, np.ndarray]:
    """Per sensor group, (n,) rows the table's own ``{group}_valid`` column flags invalid."""
    flagged: dict[str, np.ndarray] = {}
    every = np.ones(len(r.index), bool)
    for g in VALID_GROUPS:
        vcol = valid_column(g).name
        if vcol in cols.names:
            vc = cols.cells(vcol, boolean=True)
            _count_bad(tf.path, cols.label(vcol), vc.counts(rows=r.in_file(every)), g, rep)
            flagged[g] = ~(vc.values[r.index] == 1.0)
    return flagged


def _column_cells(tf: TableFile, cols: _TableColumns, names: list[str]) -> dict[str, Cells]:
    """The cells of every canonical column (labels looked up by name; raises TableError)."""
    cells: dict[str, Cells] = {}
    for c in names:
        if c.startswith("gt_state"):
            continue
        cells[c] = _label_cells(cols.raw(c), tf, cols.label(c)) if c == "terrain" and tf.label_names is not None \
            else cols.cells(c)
    return cells


def _unusable_rows(tf: TableFile, cols: _TableColumns, names: list[str], spec: dict, cells: dict[str, Cells],
                   flagged: dict[str, np.ndarray], r: _Rows, rep: IngestReport) -> dict[str, np.ndarray]:
    """Per group, (n,) rows it may not use: flagged invalid by the table, or holding a bad cell
    (counted per file column; cells on rows the table itself flags invalid are not counted)."""
    every = np.ones(len(r.index), bool)
    unusable = {spec[c].group: flagged.get(spec[c].group, ~every).copy() for c in names}
    counted: set[str] = set()
    for c, cl in cells.items():
        g = spec[c].group
        if cols.label(c) not in counted:   # one file column feeding several wheels: counted once
            counted.add(cols.label(c))
            _count_bad(tf.path, cols.label(c), cl.counts(rows=r.in_file(~flagged[g] if g in flagged else every)),
                       g, rep)
        unusable[g] |= cl.bad[r.index]
    return unusable


def _column_signal(col: str, g: str, tf: TableFile, cols: _TableColumns, cells: dict[str, Cells],
                   flagged: dict[str, np.ndarray], unusable: dict[str, np.ndarray], r: _Rows, rate_hz: float,
                   rep: IngestReport) -> Signal:
    """One canonical column of the file as a signal: one sample per stamp, NaN on unusable rows."""
    rows = r.index
    if col.startswith("gt_state"):
        codes = {**topics.WHEEL_STATE_CODES}
        v = cols.raw(col).iloc[rows].map(lambda s: codes.get(str(s), np.nan)).to_numpy(float)
        keep = np.isfinite(v)
    else:
        cl = cells[col]
        v = cl.values[rows].copy()
        if col == "terrain":
            v = np.where(v < 0, np.nan, v)      # -1: unlabelled, a sample like any other
        keep = ~cl.missing[rows] | unusable[g]   # empty cells on usable rows: no sample
        if g in VALID_GROUPS:
            v[unusable[g]] = np.nan
        own = np.isfinite(cl.values[rows])
        if not np.isfinite(v[keep]).any():
            why = ("every cell bad" if cl.bad[rows].all() else "every cell empty" if cl.missing[rows].all()
                   else f"every row flagged invalid by {g}_valid" if g in flagged and not own[~flagged[g]].any()
                   else None)   # else: the group's bad cells in another column, reported there
            if why:
                rep.warnings.append(f"{tf.path}: column '{cols.label(col)}': no usable value in {len(rows)} "
                                    f"row(s) ({why}); "
                                    f"{'group ' + g + ' 0% valid' if g in VALID_GROUPS else 'column empty'}")
    method = cols.source[col].method or (
        "previous" if col.endswith(PREVIOUS_COLUMNS) or col == "cam_confidence" else
        ("angle" if col.endswith("yaw_rad") else "linear"))
    first, _, _ = clean_times(r.t_s[keep])      # one sample per stamp (the first in file order)
    ts, v = r.t_s[keep][first], v[keep][first]
    gap = np.inf if col == "terrain" or col.startswith("gt_state") else gap_threshold_s(ts, rate_hz, tf.gap_periods)
    return Signal(col, ts, v, method, gap)


def file_signals(tf: TableFile, robot: RobotSpec, rate_hz: float, rep: IngestReport) -> FileSignals | None:
    """The canonical columns of one table file as signals (None: the reason in ``rep.errors``).

    Steps: open the file (:func:`_open_columns`), its rows in time order (:func:`_time_rows`), the
    rows the table flags invalid (:func:`_flagged_rows`), every column's cells
    (:func:`_column_cells`), the rows each group may not use (:func:`_unusable_rows`), then one
    signal per column (:func:`_column_signal`).
    """
    cols = _open_columns(tf, robot, rep)
    r = None if cols is None else _time_rows(tf, cols, rep)
    if r is None:
        return None
    spec = column_map(robot.n_wheels)
    names = [c for c in cols.names if c in spec and c not in ("t_s", "run_id", tf.time_column)
             and spec[c].group != "validity"]
    run_id = _single_run_id(cols, r)
    flagged = _flagged_rows(tf, cols, r, rep)
    try:
        cells = _column_cells(tf, cols, names)
    except TableError as exc:
        rep.errors.append(str(exc))
        return None
    unusable = _unusable_rows(tf, cols, names, spec, cells, flagged, r, rep)
    signals = [_column_signal(c, spec[c].group, tf, cols, cells, flagged, unusable, r, rate_hz, rep) for c in names]
    return FileSignals(float(r.t_s[0]), float(r.t_s[-1]), signals, names, run_id)


def tables_to_run(files: list[TableFile], robot: RobotSpec, rate_hz: float, rep: IngestReport, *,
                  span: str = "first", missing_steer_ok: bool = False) -> pd.DataFrame | None:
    """Resample the canonical columns of one run's table files onto one base grid.

    ``span``: the grid runs over the first file's time (``first``, a single table), the time
    every file covers (``overlap``) or any file covers (``union``); ``t_s`` is 0 at its start.
    ``missing_steer_ok``: fixed wheels' steering (0, filled by ``assemble``) is not reported missing.
    None (the reason in ``rep.errors``) when no table can result.
    """
    parts = []
    for tf in files:
        fs = file_signals(tf, robot, rate_hz, rep)
        if fs is None:
            return None
        parts.append(fs)
    if span == "first":
        t0, t_end = parts[0].t_first_s, parts[0].t_last_s
    elif span == "overlap":
        t0, t_end = max(p.t_first_s for p in parts), min(p.t_last_s for p in parts)
    else:
        t0, t_end = min(p.t_first_s for p in parts), max(p.t_last_s for p in parts)
    if len(files) > 1 and t_end - t0 < 1.0 / rate_hz:
        rep.errors.append(f"{', '.join(str(f.path) for f in files)}: the files do not overlap in time")
        return None
    signals = [replace(s, t_s=s.t_s - t0) for p in parts for s in p.signals]
    found = {c for p in parts for c in p.columns} | {f.time_column for f in files} | {"t_s"}
    spec = column_map(robot.n_wheels)
    fixed = {wheel_col("steer", i) for i, w in enumerate(robot.wheels, start=1) if not w.steerable}
    missing = [c.name for c in spec.values() if c.required and c.name not in found
               and not (missing_steer_ok and c.name in fixed)]
    if missing:
        rep.warnings.append(f"{files[0].path if len(files) == 1 else files[0].path.parent}: column(s) "
                            f"{', '.join(missing)} missing (group marked invalid)")
    if not signals:
        rep.errors.append(f"{files[0].path}: no canonical column found (give a topic map with 'columns')")
        return None
    run_ids = {p.run_id for p in parts if p.run_id is not None}
    if len(run_ids) == 1:
        rep.topics[files[0].role]["run_id"] = run_ids.pop()
    grid = np.arange(int(math.floor((t_end - t0) * rate_hz + 1e-6)) + 1) / rate_hz
    return assemble(signals, grid, robot)
