"""The ingest engine: logs, tables and dataset runs -> the canonical run table (design §5, contract 1).

One module per job: :mod:`~terrainml.io.ingest.loading` (the public entry points ``load_run`` and
``ingest_to_parquet``), :mod:`~terrainml.io.ingest.logs` (the log path: the chunk producer
and its passes over :mod:`~terrainml.io.ingest.log_sources`, with
:mod:`~terrainml.io.ingest.log_scan` and :mod:`~terrainml.io.ingest.log_plan`; one tick at a time
for live streams, :mod:`~terrainml.io.ingest.ticks`), :mod:`~terrainml.io.ingest.tables` (the
CSV/Parquet path, cell by cell with
:mod:`~terrainml.io.ingest.cells`), :mod:`~terrainml.io.ingest.dataset_spec` and
:mod:`~terrainml.io.ingest.dataset_runs` (multi-file datasets such as BorealTC),
:mod:`~terrainml.io.ingest.signals` and :mod:`~terrainml.io.ingest.resample` (canonical signals
onto the base grid), :mod:`~terrainml.io.ingest.table_sinks` (memory or Parquet),
:mod:`~terrainml.io.ingest.finish` (the one finish-a-run step) and
:mod:`~terrainml.io.ingest.ingest_report` (:class:`IngestReport`).
"""

from terrainml.io.ingest.dataset_runs import DatasetReport, load_dataset, load_dataset_run
from terrainml.io.ingest.ingest_report import IngestReport, IngestResult
from terrainml.io.ingest.loading import ingest_to_parquet, load_run

__all__ = ["DatasetReport", "IngestReport", "IngestResult", "ingest_to_parquet", "load_dataset",
           "load_dataset_run", "load_run"]
