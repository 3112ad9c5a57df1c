"""What ingest found (design §5): the :class:`IngestReport` of one run, and the result it travels with.

The report carries per-topic counts (read, decoded, corrupt, skipped, out of order, duplicates,
non-finite), warnings and errors naming the file, topic or column, bad cells per column for
tables, what a truncated log lost, and -- once a table results -- its rows, span, the valid
fraction per sensor group and ``usable``. :meth:`IngestReport.damage` is the ``damage`` entry of
the table's metadata (read back with :func:`terrainml.io.damage.damage_summary`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from terrainml.schema import DEFAULT_RATE_HZ, VALID_GROUPS, valid_column

__all__ = ["IngestReport", "IngestResult", "Tally"]


@dataclass
class IngestReport:
    """What ingest found: per-topic counts, warnings, and whether a usable table resulted."""

    source: str
    format: str = ""
    topics: dict[str, dict[str, Any]] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)   # e.g. optional topics absent
    usable: bool = False
    rows: int = 0
    span_s: float = 0.0
    rate_hz: float = DEFAULT_RATE_HZ
    valid_fraction: dict[str, float] = field(default_factory=dict)
    bad_cells: dict[str, dict[str, int]] = field(default_factory=dict)   # CSV/Parquet: column -> kind -> cells
    truncation: dict[str, int] | None = None     # what a truncated log lost (ReadResult.truncation)
    corrupt_chunks: int = 0

    def skipped_per_topic(self) -> dict[str, int]:
        return {t: d["skipped"] for t, d in self.topics.items() if d.get("skipped")}

    def corrupt_per_topic(self) -> dict[str, int]:
        return {t: d["corrupt"] for t, d in self.topics.items() if d.get("corrupt")}

    def to_dict(self) -> dict[str, Any]:
        return {"source": self.source, "format": self.format, "usable": self.usable, "rows": self.rows,
                "span_s": self.span_s, "rate_hz": self.rate_hz, "topics": self.topics,
                "valid_fraction": self.valid_fraction, "warnings": self.warnings, "errors": self.errors,
                "notes": self.notes, "bad_cells": self.bad_cells, "truncation": self.truncation,
                "corrupt_chunks": self.corrupt_chunks}

    def damage(self) -> dict[str, Any]:
        """The ``damage`` entry of a run table's metadata: what the source lost (unmapped topics'
        skipped messages and sorted/de-duplicated stamps are not damage)."""
        mapped = {t: d for t, d in self.topics.items() if d.get("mapped")}
        return {
            "corrupt_per_topic": self.corrupt_per_topic(),
            "skipped_per_topic": {t: int(d["skipped"]) for t, d in mapped.items() if d.get("skipped")},
            "non_finite_per_topic": {t: int(d["non_finite"]) for t, d in mapped.items() if d.get("non_finite")},
            "bad_cells_per_column": {c: dict(k) for c, k in self.bad_cells.items()},
            "corrupt_chunks": int(self.corrupt_chunks),
            "truncation": dict(self.truncation) if self.truncation else None,
        }


@dataclass
class IngestResult:
    """The canonical run table of one run (zero rows when nothing usable was found) and its report."""

    table: pd.DataFrame
    report: IngestReport


@dataclass
class Tally:
    """Row count, last tick and valid ticks per group of the chunks a sink took."""

    rows: int = 0
    last_t_s: float = 0.0
    valid: dict[str, int] = field(default_factory=lambda: {g: 0 for g in VALID_GROUPS})

    def add(self, df: pd.DataFrame) -> None:
        self.rows += len(df)
        self.last_t_s = float(df["t_s"].iloc[-1])
        for g in VALID_GROUPS:
            if valid_column(g).name in df:
                self.valid[g] += int(df[valid_column(g).name].sum())

    def finish(self, rep: IngestReport, path: Path) -> None:
        """Rows, span, valid fractions and ``usable`` into the report."""
        rep.rows, rep.span_s = self.rows, self.last_t_s
        rep.valid_fraction = {g: v / self.rows for g, v in self.valid.items()} if self.rows else {}
        rep.usable = self.rows >= 2 and any(rep.valid_fraction.get(g, 0.0) > 0 for g in ("wheels", "imu", "cam"))
        if not rep.usable:
            rep.errors.append(f"{path}: no valid wheel, IMU or camera sample on the base grid")
