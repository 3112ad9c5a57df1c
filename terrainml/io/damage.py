"""Damage counts that travel with a run table (design §5).

Ingest stores what it could not read in the table's metadata (``df.attrs["terrainml"]["damage"]``
and the same JSON in the Parquet key-value metadata): corrupt, skipped and non-finite messages per
topic, bad cells per column (CSV/Parquet), corrupt chunks, and what a truncated file lost. Every
later step reads it back with one call::

    from terrainml.io.damage import damage_summary
    d = damage_summary(table)          # a run table, its metadata dict, a Parquet path or an IngestReport
    if d.any:
        print(d.text)                  # "damaged: 412 corrupt message(s) (/imu 206, ...); ..."

Only damage counts: messages of topics the topic map does not use are not (they are skipped on
purpose), nor are sorted or de-duplicated stamps (nothing is lost).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import pandas as pd
import pyarrow.parquet as pq

from terrainml.io.ingest.ingest_report import IngestReport
from terrainml.schema import METADATA_KEY

__all__ = ["DamageSummary", "damage_summary"]

_LISTED = 3   # per-topic / per-column entries named in the one-line text


@dataclass(frozen=True)
class DamageSummary:
    """What a run's source log lost. Totals, per-topic and per-column counts, one line of text."""

    corrupt_per_topic: dict[str, int] = field(default_factory=dict)     # unreadable messages
    skipped_per_topic: dict[str, int] = field(default_factory=dict)     # mapped topic, wrong type
    non_finite_per_topic: dict[str, int] = field(default_factory=dict)  # messages with NaN/Inf fields
    bad_cells_per_column: dict[str, int] = field(default_factory=dict)  # CSV/Parquet cells
    bad_cells_by_kind: dict[str, dict[str, int]] = field(default_factory=dict)
    corrupt_chunks: int = 0
    truncation: dict[str, int] | None = None   # unread_bytes, missing_bytes, incomplete_records, ...
    corrupt_messages: int = 0
    skipped_messages: int = 0
    non_finite_messages: int = 0
    bad_cells: int = 0
    lost_bytes: int = 0                        # truncated file: bytes after the last complete record
    any: bool = False
    text: str = "no damage"

    def to_dict(self) -> dict[str, Any]:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


def _damage_dict(obj: Any) -> dict[str, Any]:
    if isinstance(obj, IngestReport):
        return obj.damage()
    if isinstance(obj, pd.DataFrame):
        obj = obj.attrs.get("terrainml", {})
    elif isinstance(obj, (str, Path)):
        kv = pq.read_schema(obj).metadata or {}
        obj = json.loads(kv[METADATA_KEY]) if METADATA_KEY in kv else {}
    if not isinstance(obj, Mapping):
        raise TypeError(f"damage_summary takes a run table, its metadata, a Parquet path or an IngestReport; "
                        f"got {type(obj).__name__}")
    if isinstance(obj.get("damage"), Mapping):
        return dict(obj["damage"])
    # a table written before damage was recorded: its corrupt counts only (skipped_per_topic
    # there also counts unmapped topics, which is not damage)
    return {"corrupt_per_topic": dict(obj.get("corrupt_per_topic") or {})}


def _listed(counts: Mapping[str, int]) -> str:
    items = sorted(counts.items(), key=lambda kv: -kv[1])
    text = ", ".join(f"{k} {v:,}" for k, v in items[:_LISTED])
    return text + (f", +{len(items) - _LISTED} more" if len(items) > _LISTED else "")


def damage_summary(table_or_metadata: Any) -> DamageSummary:
    """The damage a run table carries.

    Parameters
    ----------
    table_or_metadata : a run table (``df.attrs["terrainml"]``), its metadata dict (or just its
        ``damage`` entry), a run-table Parquet path (only its metadata is read) or an IngestReport.

    Returns
    -------
    DamageSummary; ``any`` is False and ``text`` "no damage" for a clean log.
    """
    d = _damage_dict(table_or_metadata)
    corrupt = {k: int(v) for k, v in (d.get("corrupt_per_topic") or {}).items() if v}
    skipped = {k: int(v) for k, v in (d.get("skipped_per_topic") or {}).items() if v}
    non_finite = {k: int(v) for k, v in (d.get("non_finite_per_topic") or {}).items() if v}
    by_kind = {c: {k: int(n) for k, n in kinds.items()} for c, kinds in (d.get("bad_cells_per_column") or {}).items()}
    cells = {c: sum(k.values()) for c, k in by_kind.items() if sum(k.values())}
    trunc = d.get("truncation") or None
    chunks = int(d.get("corrupt_chunks") or 0)
    parts = []
    if corrupt:
        parts.append(f"{sum(corrupt.values()):,} corrupt message(s) ({_listed(corrupt)})"
                     + (f" in {chunks} corrupt chunk(s)" if chunks else ""))
    elif chunks:
        parts.append(f"{chunks} corrupt chunk(s)")
    if skipped:
        parts.append(f"{sum(skipped.values()):,} message(s) of the wrong type skipped ({_listed(skipped)})")
    if non_finite:
        parts.append(f"{sum(non_finite.values()):,} message(s) with NaN/Inf ({_listed(non_finite)})")
    if cells:
        parts.append(f"{sum(cells.values()):,} bad cell(s) ({_listed(cells)})")
    if trunc:
        parts.append(f"truncated: {int(trunc.get('unread_bytes', 0)):,} byte(s) unread, "
                     f"{int(trunc.get('incomplete_records', 0))} incomplete record(s)")
    any_damage = bool(parts)
    return DamageSummary(
        corrupt_per_topic=corrupt, skipped_per_topic=skipped, non_finite_per_topic=non_finite,
        bad_cells_per_column=cells, bad_cells_by_kind=by_kind, corrupt_chunks=chunks, truncation=trunc,
        corrupt_messages=sum(corrupt.values()), skipped_messages=sum(skipped.values()),
        non_finite_messages=sum(non_finite.values()), bad_cells=sum(cells.values()),
        lost_bytes=int(trunc.get("unread_bytes", 0)) if trunc else 0, any=any_damage,
        text="damaged: " + "; ".join(parts) if any_damage else "no damage")
