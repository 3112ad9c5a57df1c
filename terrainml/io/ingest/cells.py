"""Cell-level validation of CSV and Parquet columns (design §5).

Every cell of a canonical column is one of

* **missing** -- an empty CSV cell or a Parquet null: no sample in this row (a sparse, multi-rate
  table); the column's other rows are resampled as if the row were not there;
* **good** -- a finite number (validity columns: a boolean, 0/1, or the text true/false, yes/no, t/f);
* **bad** -- counted per column by kind and never turned into a valid-looking value:
  ``unparseable`` (text that is not a number, e.g. ``"n/a"``, ``"abc"``; in a validity column
  any other text or number), ``non_finite`` (``inf``, ``-inf``, the text ``nan`` or a non-null
  NaN) or ``wrong_type`` (a list, struct, binary or date cell).

Ingest keeps a bad cell as a NaN sample, so the ticks it touches are invalid and nothing is
interpolated or held across it (:func:`terrainml.io.ingest.tables.file_signals`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc

KINDS = ("unparseable", "non_finite", "wrong_type")
_NAN_TEXT = {"nan", "+nan", "-nan"}
_TRUE = {"true", "t", "yes", "y", "1", "1.0"}
_FALSE = {"false", "f", "no", "n", "0", "0.0"}


@dataclass
class Cells:
    """One column's cells as numbers."""

    values: np.ndarray                 # (n,) float64; NaN where missing or bad
    missing: np.ndarray                # (n,) bool: empty / null cell, no sample in this row
    bad: np.ndarray                    # (n,) bool: unparseable, non-finite or wrongly typed
    kinds: dict[str, np.ndarray] = field(default_factory=dict)   # kind -> (n,) bool, bad cells of it

    def counts(self, rows: np.ndarray | None = None) -> dict[str, int]:
        """Bad cells per kind (among ``rows``, bool (n,), when given); non-zero kinds only."""
        out = {k: int(np.count_nonzero(m if rows is None else m & rows)) for k, m in self.kinds.items()}
        return {k: n for k, n in out.items() if n}


def _make(values: np.ndarray, missing: np.ndarray, kinds: dict[str, np.ndarray]) -> Cells:
    bad = np.zeros(len(values), bool)
    for m in kinds.values():
        bad |= m
    return Cells(np.where(bad | missing, np.nan, values), missing, bad, kinds)


def _object_cells(obj: np.ndarray, missing: np.ndarray, boolean: bool) -> Cells:
    """Cells of an object column (text, numbers, or anything else)."""
    n = len(obj)
    is_str = np.fromiter((isinstance(x, str) for x in obj), bool, n)
    is_num = np.fromiter((isinstance(x, (bool, int, float, np.number)) for x in obj), bool, n)
    text = np.array([x.strip().lower() if isinstance(x, str) else "" for x in obj], dtype=object)
    missing = missing | (is_str & (text == ""))
    wrong = ~missing & ~is_str & ~is_num
    if boolean:
        vals = np.full(n, np.nan)
        vals[np.isin(text, list(_TRUE))] = 1.0
        vals[np.isin(text, list(_FALSE))] = 0.0
        num = pd.to_numeric(pd.Series(np.where(is_num, obj, None)), errors="coerce").to_numpy(float)
        vals = np.where(is_num & np.isin(num, (0.0, 1.0)), num, vals)
        unparse = ~missing & ~wrong & np.isnan(vals)
        return _make(vals, missing, {"unparseable": unparse, "wrong_type": wrong})
    num = pd.to_numeric(pd.Series(np.where(is_str | is_num, obj, None)), errors="coerce").to_numpy(float)
    nan_text = is_str & np.isin(text, list(_NAN_TEXT))
    usable = ~missing & ~wrong
    non_finite = usable & (nan_text | np.isinf(num) | (is_num & np.isnan(num)))
    unparse = usable & np.isnan(num) & ~nan_text & ~(is_num & np.isnan(num))
    return _make(num, missing, {"unparseable": unparse, "non_finite": non_finite, "wrong_type": wrong})


def _numeric(values: np.ndarray, missing: np.ndarray, boolean: bool) -> Cells:
    if boolean:
        unparse = ~missing & ~np.isin(values, (0.0, 1.0))
        return _make(values, missing, {"unparseable": unparse})
    return _make(values, missing, {"non_finite": ~missing & ~np.isfinite(values)})


def series_cells(s: pd.Series, *, boolean: bool = False) -> Cells:
    """Cells of a pandas column (CSV read with only empty cells as NA)."""
    missing = s.isna().to_numpy(bool)
    if pd.api.types.is_bool_dtype(s) or pd.api.types.is_numeric_dtype(s):
        return _numeric(s.to_numpy(dtype=float, na_value=np.nan), missing, boolean)
    return _object_cells(s.to_numpy(dtype=object, na_value=None), missing, boolean)


def arrow_cells(col: pa.ChunkedArray, *, boolean: bool = False) -> Cells:
    """Cells of a Parquet column: nulls are missing, a non-null NaN is non-finite."""
    t = col.type
    if pa.types.is_dictionary(t):
        col = col.cast(t.value_type)
        t = col.type
    missing = pc.is_null(col).to_numpy(zero_copy_only=False).astype(bool)
    if pa.types.is_integer(t) or pa.types.is_floating(t) or pa.types.is_boolean(t) or pa.types.is_decimal(t):
        vals = pc.cast(col, pa.float64()).fill_null(0.0).to_numpy(zero_copy_only=False).astype(float)
        return _numeric(vals, missing, boolean)
    if pa.types.is_string(t) or pa.types.is_large_string(t) or pa.types.is_null(t):
        obj = np.empty(len(col), dtype=object)
        obj[:] = col.to_pylist()
        return _object_cells(obj, missing, boolean)
    n = len(col)
    return _make(np.full(n, np.nan), missing, {"wrong_type": ~missing})
