"""Where the log path's chunks of the run table go (design §5): memory or a Parquet file.

:func:`terrainml.io.ingest.logs.produce` hands chunks of ticks, in order, to a sink:
:class:`FrameSink` keeps them and joins them into one DataFrame (``load_run``); :class:`ParquetSink`
appends each as a row group to a hidden ``.part`` file moved over the output only when the
table is usable (``ingest_to_parquet``: memory bounded by one chunk).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from terrainml.atomic import discard, output_error, part_path
from terrainml.io.ingest.ingest_report import Tally
from terrainml.schema import METADATA_KEY, validate_run_table

__all__ = ["FrameSink", "ParquetSink"]


@dataclass
class FrameSink:
    """Chunks kept in memory and joined into one DataFrame (``load_run``)."""

    chunks: list[pd.DataFrame] = field(default_factory=list)

    def write(self, chunk: pd.DataFrame) -> None:
        self.chunks.append(chunk)

    def table(self) -> pd.DataFrame | None:
        if not self.chunks:
            return None
        return self.chunks[0] if len(self.chunks) == 1 else pd.concat(self.chunks, ignore_index=True)


@dataclass
class ParquetSink:
    """Chunks appended to a Parquet file as row groups (``ingest_to_parquet``): written to a
    hidden ``.part`` file beside ``out``, moved over ``out`` only when the table is usable."""

    out: Path
    meta: dict[str, Any]
    run_id: str
    n_wheels: int
    tally: Tally = field(default_factory=Tally)
    writer: pq.ParquetWriter | None = None
    schema: pa.Schema | None = None

    @property
    def tmp(self) -> Path:
        return part_path(self.out)

    def write(self, chunk: pd.DataFrame) -> None:
        """Append ``chunk``; a failed write raises :class:`terrainml.atomic.OutputWriteError` naming ``out``."""
        try:
            self._write(chunk)
        except OSError as exc:   # a full disk: name the output, not the log being read
            raise output_error(exc, self.out) from None

    def _write(self, chunk: pd.DataFrame) -> None:
        chunk["run_id"] = self.run_id
        if self.writer is None:  # every chunk has the same columns and dtypes: check the first,
            chunk = validate_run_table(chunk, self.n_wheels, source=self.meta["source_file"])  # the
            table = pa.Table.from_pandas(chunk, preserve_index=False)          # Parquet schema the rest
            kv = dict(table.schema.metadata or {})
            kv[METADATA_KEY] = json.dumps(self.meta, default=str).encode()
            self.schema = table.schema.with_metadata(kv)
            self.out.parent.mkdir(parents=True, exist_ok=True)
            self.writer = pq.ParquetWriter(self.tmp, self.schema)
        # columns straight to Arrow (pandas' converter is ~2x slower per chunk)
        text = (pa.types.is_string, pa.types.is_large_string)
        table = pa.Table.from_arrays([pa.array(chunk[f.name].to_numpy(dtype=object if any(k(f.type) for k in text)
                                                                      else None), type=f.type)
                                      for f in self.schema], schema=self.schema)
        self.writer.write_table(table)
        self.tally.add(chunk)

    def close(self, keep: bool) -> None:
        """Finish the file; move it to ``out`` when ``keep``, else leave nothing behind.

        A failure to finish or move it leaves nothing either and raises
        :class:`terrainml.atomic.OutputWriteError` naming ``out``.
        """
        try:
            if self.writer is not None:
                self.writer.close()
            if keep:
                os.replace(self.tmp, self.out)
                return
        except OSError as exc:
            discard(self.tmp)
            raise output_error(exc, self.out) from None
        except BaseException:
            discard(self.tmp)
            raise
        discard(self.tmp)
