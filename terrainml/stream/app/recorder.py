"""Unknown ground handed back for labelling: ``terrainml predict --record-unknown DIR``.

:class:`UnknownGroundRecorder` takes every served message with its sample (``send(msg, sample)``,
as :func:`terrainml.stream.app.runner.serve` hands them over) and writes each *stretch* of consecutive
ticks served ``unknown_terrain`` as one run into ``DIR``:

* ``unknown_<UTC start of serving>_<NNN>.parquet``: the canonical run-table rows (design §5) of
  exactly those ticks, as the source gave them (the sample's canonical columns; extras dropped),
  ``terrain`` = -1 (unlabelled) and ``run_id`` = the file's stem, written with
  :func:`terrainml.schema.write_run_parquet` (whole or not at all). Its metadata carries the
  model's class names (``classes``: the ids a label refers to) and the sidecar's facts.
* or, with ``fmt="mcap"`` (``--record-format mcap``), ``unknown_<...>_<NNN>.mcap``: the same rows
  as a ROS 2 MCAP log with the default topic map's messages (design §5), written by
  :func:`terrainml.io.mcap_writer.write_run_mcap` with the robot the predictor serves (its IMU
  and camera mounts), to open in Foxglove or ingest again (``terrainml ingest``). A message's log
  time is the sample's ROS time, ``stamp_origin_ns + t_s`` of a ROS 2 source (as the ROS 2 sink
  stamps), else ``t_s`` itself (ns since 1970-01-01); the MCAP's ``terrainml`` metadata record
  carries the class names and the sidecar. No ``/terrain/label`` messages (the ground has none
  yet); ``wheel{i}_cmd_omega_radps`` has no topic and is not written.
* ``unknown_<...>_<NNN>.json``: the sidecar: the run file and its format, first and last ``t_s``
  of the stretch, its duration, ticks, the distance the odometer travelled over it, the model
  folder, the robot, the mean and max novelty (score over the threshold) of its ticks,
  ``label``: null (for the person who labels it).

A stretch ends at the first tick served otherwise (a class, or another fallback such as
``stale``); one longer than ``max_rows`` ticks is written in parts, so memory stays bounded.
Once a person sets the ``terrain`` column (docs/stream.md "Unknown ground"), ``terrainml dataset
build`` takes the folder like any folder of Parquet runs (an MCAP run is ingested to Parquet
first, beside its sidecar, then labelled: :func:`terrainml.pipeline.labels.label_run`).

The recorder never stops or stalls the tick loop: a finished stretch is written by one background
thread (a Parquet or MCAP file of up to ``max_rows`` rows is too slow for a 10 ms tick), and
:meth:`close` waits for the writes; :meth:`send` and :meth:`close` catch everything; a run that
cannot be written (a full disk, rows the schema refuses) is counted in ``failed`` with its error
in ``errors`` (the message names the file), for the end-of-stream summary. Both formats are
written whole or not at all (a hidden ``.NAME.part`` renamed when complete, :mod:`terrainml.atomic`).
"""

from __future__ import annotations

import json
import logging
import math
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np
import pandas as pd

from terrainml.atomic import write_text
from terrainml.io.mcap_writer import write_run_mcap
from terrainml.robot import RobotSpec
from terrainml.schema import column_map, validate_run_table, write_run_parquet
from terrainml.stream.tick.message import UNKNOWN_TERRAIN
from terrainml.stream.tick.sample import NO_SAMPLE, Sample
from terrainml.stream.transports.ros2.source import STAMP_ORIGIN_KEY

__all__ = ["UnknownGroundRecorder", "MAX_ROWS", "RECORD_FORMATS"]

log = logging.getLogger("terrainml.stream")

#: a stretch longer than this many ticks is written in parts (10 min at 100 Hz)
MAX_ROWS = 60_000
#: the formats a stretch can be written in (``--record-format``), the first the default
RECORD_FORMATS = ("parquet", "mcap")
_LABELS = ("terrain", "run_id")


class UnknownGroundRecorder:
    """Write each stretch of ``unknown_terrain`` ticks as a run (module docstring).

    Parameters
    ----------
    folder : the output folder, created (OSError when it cannot be).
    n_wheels : the robot's wheels (the run table's columns). class_names : the model's class
        names by class id (written as the run's ``classes``). model : the model folder (sidecar).
    distance : callable returning the odometer's distance (m) after the latest tick.
    max_rows : ticks per written part.
    fmt : ``parquet`` (default) or ``mcap`` (:data:`RECORD_FORMATS`, any case).
    robot : the RobotSpec served (its name goes in the sidecar); required for ``mcap``, whose
        messages are in the IMU's and camera's own frames (its mounts), with ``n_wheels`` wheels.

    Raises
    ------
    ValueError
        An unknown ``fmt``, ``mcap`` without a robot, or a robot of another wheel count (before
        the folder is created).

    Attributes
    ----------
    written : list of the run files written (``.parquet`` or ``.mcap``). failed : runs that
        could not be written. errors : their messages (each names the file).
    """

    name = "record-unknown"

    def __init__(self, folder: str | Path, *, n_wheels: int, class_names: Sequence[str], model: str,
                 distance: Callable[[], float], max_rows: int = MAX_ROWS, fmt: str = RECORD_FORMATS[0],
                 robot: RobotSpec | None = None):
        self.fmt = str(fmt).strip().lower()
        if self.fmt not in RECORD_FORMATS:
            raise ValueError(f"record format {fmt!r}: expected one of {', '.join(RECORD_FORMATS)}")
        if self.fmt == "mcap" and robot is None:
            raise ValueError("record format mcap: needs the robot (its IMU and camera mounts)")
        if robot is not None and robot.n_wheels != int(n_wheels):
            raise ValueError(f"robot {robot.name} has {robot.n_wheels} wheels, the recorder {n_wheels}")
        self.robot = robot
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.n_wheels = int(n_wheels)
        self.class_names = [str(c) for c in class_names]
        self.model = str(model)
        self.distance = distance
        self.max_rows = int(max_rows)
        self.columns = set(column_map(self.n_wheels)) - set(_LABELS)
        self.prefix = "unknown_" + time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
        self.written: list[Path] = []
        self.failed = 0
        self.errors: list[str] = []
        self._n = 0
        self._rows: list[dict] | None = None
        self._novelty: list[float] = []
        self._span: dict[str, float] = {}
        self._origin_ns = 0
        self._writer = ThreadPoolExecutor(max_workers=1, thread_name_prefix="record-unknown")

    def send(self, msg: Any, sample: Sample = NO_SAMPLE) -> None:
        """Take one served message and the sample it was served from (never raises)."""
        try:
            if msg.fallback_reason == UNKNOWN_TERRAIN:
                self._take(msg, sample.columns)
            elif self._rows is not None:
                self._flush()
        except Exception as exc:  # noqa: BLE001 - the recorder must never stop serving
            self._fail(f"{self.folder}: recording unknown ground failed at t={getattr(msg, 't_s', math.nan)} s: "
                       f"{type(exc).__name__}: {exc}")
            self._rows = None

    def close(self) -> None:
        """Write the stretch still open at the end of the stream (never raises)."""
        try:
            if self._rows is not None:
                self._flush()
        except Exception as exc:  # noqa: BLE001
            self._fail(f"{self.folder}: {type(exc).__name__}: {exc}")
        self._writer.shutdown(wait=True)

    def summary(self) -> str:
        """The end-of-stream summary line."""
        text = f"recorded unknown ground: {len(self.written)} run(s) in {self.folder}"
        if self.failed:
            text += f"; {self.failed} failed write(s) (first: {self.errors[0]})"
        return text

    # ------------------------------------------------------------------ parts
    def _take(self, msg: Any, sample: Mapping[str, Any]) -> None:
        if self._rows is None:
            self._rows, self._novelty = [], []
            self._span = {"t_start_s": float(msg.t_s), "d_start_m": float(self.distance())}
            origin = sample.get(STAMP_ORIGIN_KEY, 0)   # ROS time = origin + t_s (a ROS 2 source)
            self._origin_ns = origin if isinstance(origin, int) and not isinstance(origin, bool) else 0
        self._rows.append({k: v for k, v in sample.items() if k in self.columns})
        self._span["t_end_s"], self._span["d_end_m"] = float(msg.t_s), float(self.distance())
        nov = float(getattr(msg, "novelty", -1.0))
        if math.isfinite(nov) and nov >= 0:
            self._novelty.append(nov)
        if len(self._rows) >= self.max_rows:
            self._flush()

    def _flush(self) -> None:
        rows, self._rows = self._rows or [], None
        self._n += 1
        # never overwrite a run or a sidecar (a recording of the other format may share the stem)
        while any((self.folder / f"{self.prefix}_{self._n:03d}{ext}").exists() for ext in (".parquet", ".mcap",
                                                                                             ".json")):
            self._n += 1
        stem = f"{self.prefix}_{self._n:03d}"
        path = self.folder / f"{stem}.{self.fmt}"
        side = self._sidecar(stem, len(rows))
        self._writer.submit(self._write, rows, stem, path, side)

    def _write(self, rows: list[dict], stem: str, path: Path, side: dict) -> None:
        """Write one run and its sidecar (the writer thread); a failure is counted, never raised."""
        try:
            df = pd.DataFrame(rows)
            df["terrain"] = np.full(len(df), -1, dtype=np.int64)
            df["run_id"] = stem
            df = validate_run_table(df, self.n_wheels, source=str(path))
            meta = {"classes": self.class_names, "unknown_ground": side,
                    "source_file": f"terrainml predict --model {self.model}"}
            if self.fmt == "mcap":
                write_run_mcap(df, path, self.robot, start_time_ns=side["log_time_origin_ns"],
                               metadata={k: json.dumps(v, sort_keys=True) for k, v in meta.items()})
            else:
                write_run_parquet(df, path, metadata=meta)
            write_text(path.with_suffix(".json"), json.dumps(side, indent=2, sort_keys=True) + "\n")
        except Exception as exc:  # noqa: BLE001 - counted and reported, serving goes on
            self._fail(f"{path}: not written: {type(exc).__name__}: {exc}")
            return
        self.written.append(path)

    def _sidecar(self, stem: str, n_rows: int) -> dict:
        sp, nov = self._span, self._novelty
        side = {"run": f"{stem}.{self.fmt}", "format": self.fmt, "run_id": stem, "t_start_s": sp["t_start_s"],
                "t_end_s": sp["t_end_s"], "duration_s": sp["t_end_s"] - sp["t_start_s"], "ticks": int(n_rows),
                "distance_m": sp["d_end_m"] - sp["d_start_m"], "model": self.model,
                "robot": None if self.robot is None else self.robot.name,
                "mean_novelty": float(np.mean(nov)) if nov else None,
                "max_novelty": float(np.max(nov)) if nov else None,
                "fallback_reason": UNKNOWN_TERRAIN, "classes": self.class_names, "label": None}
        if self.fmt == "mcap":  # a message's log time (ns) = this + round(t_s * 1e9)
            side["log_time_origin_ns"] = self._origin_ns
        return side

    def _fail(self, text: str) -> None:
        self.failed += 1
        self.errors.append(text)
        if self.failed == 1 or self.failed % 100 == 0:
            log.warning("%s (%d failed so far; predictor continues)", text, self.failed)
