"""The log path of the ingest engine: scan, plan, chunk producer (design §5, contract 1).

The logs are :mod:`~terrainml.io.ingest.log_sources`, the scan :mod:`~terrainml.io.ingest.log_scan`,
the plan :mod:`~terrainml.io.ingest.log_plan`; this module produces the table and runs the passes
(their names are importable from here too).

One engine behind ``load_run`` (a DataFrame sink) and ``ingest_to_parquet`` (a Parquet sink). A log
hands decoded parts (:mod:`terrainml.io.cdr`) to a consumer in file order: :class:`FileLog` re-reads
the file for every pass (bounded memory), :class:`MemoryLog` reads it once and replays the parts.

1. **scan** -- every mapped message is reduced at once to constant-size facts: time origin, grid
   end, per-topic counts, the first valid T265 pose (yaw zeroing), whether the IMU ever publishes
   an orientation, which joints exist, how late a message can arrive (``lateness``) and each
   source's gap threshold ``2 * max(base period, median period)`` (exact in O(1) memory for sources
   at or above the base rate; a slower one keeps its larger stamp differences). A topic whose
   stamps are out of order gets one more pass over that topic alone (damaged logs only).
2. **plan** -- report counts and warnings, per-source columns and gap thresholds, grid length; a
   joint_state topic whose wheel count (joint names matching the map's ``{i}`` templates) differs
   from the robot spec's is refused (:func:`terrainml.robot.check_wheel_count`).
3. **produce** -- parts merge into per-source buffers (sorted, duplicate stamps dropped, first in
   file order kept). A chunk of ticks ``[ga, gb]`` is resampled once every source is *settled* past
   ``gb`` (its sample after ``gb`` is known and no earlier one can still arrive, or no unseen sample
   can bracket a tick within the gap threshold, or the source is exhausted). A source slice holds the
   last sample at or before ``ga`` and the first after ``gb``, so interpolation, hold and the gap
   rule see what they see on the whole log. The last hole tick (no sensor group valid) is carried
   from chunk to chunk, so labels are never held across a hole (:func:`terrainml.io.ingest.signals.assemble`).

Damaged-log edge cases: the non-finite count and the IMU "orientation never set" test are taken
before duplicate stamps of an out-of-order topic are dropped; a joint in several joint-name sets of
one topic breaks ties between equal stamps by file order.
"""

from __future__ import annotations

from pathlib import Path
from typing import Protocol

import numpy as np
import pandas as pd

from terrainml.io.ingest.log_plan import Buffer as Buffer, Plan as Plan, label_period_s as label_period_s, plan
from terrainml.io.ingest.log_scan import DRAIN_ROWS, Scan, Series as Series, TopicScan as TopicScan
from terrainml.io.ingest.log_sources import FileLog, MemoryLog as MemoryLog, OnPart as OnPart
from terrainml.io.ingest.ingest_report import IngestReport
from terrainml.io.ingest.resample import _EPS
from terrainml.io.ingest.signals import Signal, assemble, last_hole_s, signals_for
from terrainml.io.read_result import ReadResult
from terrainml.io.topicmap import TopicMap
from terrainml.robot import RobotSpec

__all__ = ["DRAIN_ROWS", "OnPart", "FileLog", "MemoryLog", "Series", "TopicScan", "Scan", "Buffer", "Plan",
           "label_period_s", "plan", "Sink", "Producer", "scan_log", "produce"]


class Sink(Protocol):
    def write(self, chunk: pd.DataFrame) -> None:
        """Take the next chunk of the run table (ticks in order, ``run_id`` not yet set)."""


class Producer:
    """Pass 2: merges decoded parts into per-source buffers and hands settled chunks of ticks to a
    sink. ``drain_rows`` None: merge only at the end (a replayed in-memory log)."""

    def __init__(self, p: Plan, tmap: TopicMap, robot: RobotSpec, rate_hz: float, chunk_ticks: int,
                 sink: Sink, drain_rows: int | None = DRAIN_ROWS):
        self.plan, self.tmap, self.robot, self.rate_hz = p, tmap, robot, rate_hz
        self.scan, self.t0 = p.scan, p.t0_ns
        self.chunk_ticks, self.sink, self.drain_rows = chunk_ticks, sink, drain_rows
        self.next_tick = 0
        self.rows_seen: dict[str, int] = {}
        self.topic_max: dict[str, int] = {}
        self.all_max: int | None = None
        self.pending_rows = 0
        self.hole_s = -np.inf     # last tick of the table so far with no sensor group valid
        self.by_topic: dict[str, list[Buffer]] = {}
        for buf in p.buffers:
            self.by_topic.setdefault(buf.topic, []).append(buf)

    # -- input
    def on_part(self, topic: str, part: dict) -> None:
        t = part["t_ns"]
        n = len(t)
        if n == 0 or topic not in self.scan.topics:
            return
        hi = int(t[0]) if n == 1 else int(t.max())
        self.all_max = hi if self.all_max is None else max(self.all_max, hi)
        self.topic_max[topic] = max(self.topic_max.get(topic, hi), hi)
        self.rows_seen[topic] = self.rows_seen.get(topic, 0) + n
        for buf in self.by_topic.get(topic, ()):
            if buf.joint is None:
                buf.pending.append(part)
            elif buf.joint in part["names"]:
                k = part["names"].index(buf.joint)
                buf.pending.append({"t_ns": t, **{f: part[f][:, k] for f in buf.fields}})
        self.pending_rows += n
        if self.drain_rows is not None and self.pending_rows >= self.drain_rows:
            self.drain(final=False)

    # -- settling
    def _frontier_ns(self, topic: str, final: bool) -> float:
        """Every sample of ``topic`` stamped before the frontier has been read (lateness bound)."""
        ts = self.scan.topics[topic]
        if final or self.rows_seen.get(topic, 0) >= ts.rows:
            return np.inf
        f = -np.inf
        if topic in self.topic_max:
            f = self.topic_max[topic] - ts.lateness_ns
        if self.all_max is not None:
            f = max(f, self.all_max - self.scan.lateness_all_ns)
        return f

    def _settled(self, buf: Buffer, gb: float, frontier_ns: float) -> bool:
        """Can ticks up to ``gb`` be resampled from this buffer exactly as on the whole log?"""
        if frontier_ns == np.inf:
            return True
        t = buf.t_ns()
        if len(t):  # the sample after gb is known and nothing earlier can still arrive
            j = int(np.searchsorted((t - self.t0) * 1e-9, gb + _EPS, side="right"))
            if j < len(t) and t[j] <= frontier_ns:
                return True
        # any unseen sample is too far away to bracket a tick of the chunk within the gap rule
        return (frontier_ns - self.t0) * 1e-9 > gb + buf.need_gap_s + 1e-6

    def drain(self, final: bool) -> None:
        for buf in self.plan.buffers:
            buf.merge()
        self.pending_rows = 0
        fronts = {topic: self._frontier_ns(topic, final) for topic in self.scan.topics}
        while self.next_tick < self.plan.n_ticks:
            a = self.next_tick
            b = min(a + self.chunk_ticks, self.plan.n_ticks)
            gb = (b - 1) / self.rate_hz
            if not all(self._settled(buf, gb, fronts[buf.topic]) for buf in self.plan.buffers):
                return
            self._emit_chunk(a, b)
            self.next_tick = b

    # -- output
    def _emit_chunk(self, a: int, b: int) -> None:
        grid = np.arange(a, b) / self.rate_hz
        ga, gb, ga_next = grid[0], grid[-1], b / self.rate_hz
        signals: list[Signal] = []
        for buf in self.plan.buffers:
            ts = (buf.t_ns() - self.t0) * 1e-9
            if len(ts):
                lo = max(int(np.searchsorted(ts, ga + _EPS, side="right")) - 1, 0)
                hi = min(int(np.searchsorted(ts, gb + _EPS, side="right")), len(ts) - 1)
                sl = slice(lo, hi + 1)
            else:
                sl = slice(0, 0)
            signals += self._signals(buf, sl, ts[sl])
            if b == self.plan.n_ticks:   # the last chunk: nothing of the buffer is needed any more
                buf.data = {}
            elif len(ts):  # keep from the last sample at or before the next chunk's first tick
                keep = max(int(np.searchsorted(ts, ga_next + _EPS, side="right")) - 1, 0)
                if keep:
                    buf.data = {k: (v[keep:] if isinstance(v, np.ndarray) else v) for k, v in buf.data.items()}
        chunk = assemble(signals, grid, self.robot, self.hole_s)
        self.hole_s = last_hole_s(chunk, self.hole_s)
        self.sink.write(chunk)

    def _signals(self, buf: Buffer, sl: slice, t_s: np.ndarray) -> list[Signal]:
        if not len(t_s):
            return [Signal(s.column, t_s, np.zeros(0), s.method, s.max_gap_s, period_s=s.period_s)
                    for s in buf.signals]
        if buf.joint is not None:
            return [Signal(s.column, t_s, buf.data[f][sl], s.method, s.max_gap_s)
                    for s, f in zip(buf.signals, buf.fields)]
        part = {k: (v[sl] if isinstance(v, np.ndarray) else v) for k, v in buf.data.items()}
        return signals_for(self.scan.topics[buf.topic].src, part, t_s, self.robot, self.tmap,
                           self.plan.facts[buf.topic])


# ----------------------------------------------------------------------------- passes
def _report_read(path: Path, res: ReadResult, tmap: TopicMap, mismatched: dict[str, str],
                 rep: IngestReport) -> None:
    """Per-topic counts and the reader's warnings into the report."""
    by_topic = tmap.by_topic()
    rep.warnings.extend(res.warnings)
    rep.truncation, rep.corrupt_chunks = res.truncation(), res.corrupt_chunks
    for topic, st in res.stats.items():
        rep.topics[topic] = {"type": st.type, "mapped": topic in by_topic, "read": st.read,
                             "decoded": st.decoded, "corrupt": st.corrupt, "skipped": st.skipped,
                             "out_of_order": 0, "duplicates": 0, "non_finite": 0}
        if st.corrupt:
            rep.warnings.append(f"{path}: topic {topic}: {st.corrupt} corrupt message(s) skipped")
    if res.unattributed_corrupt:
        rep.topics.setdefault("<unknown channel>", {"type": "", "mapped": False, "read": 0, "decoded": 0,
                                                    "corrupt": res.unattributed_corrupt, "skipped": 0})
    for topic, type_name in mismatched.items():
        src = by_topic[topic]
        rep.warnings.append(f"{path}: topic {topic} has type {type_name}, the topic map expects "
                            f"{src.type or src.decode_kind}: {res.stats[topic].read} message(s) skipped")
    for src in tmap.sources:
        if src.topic not in res.stats:
            (rep.notes if src.options.get("optional") else rep.warnings).append(
                f"{path}: mapped topic {src.topic} ({src.type or src.kind}) is not in the log")


def scan_log(log: FileLog, tmap: TopicMap, robot: RobotSpec, rate_hz: float, rep: IngestReport) -> Plan | None:
    """Pass 1 and the plan; None (the reason in ``rep.errors``) when no table can result."""
    scan = Scan(tmap, robot, rate_hz, None if log.kept else DRAIN_ROWS)
    res = log.read(scan.on_part)
    scan.drain()
    _report_read(log.path, res, tmap, log.mismatched, rep)
    p = plan(scan, log, tmap, robot, rate_hz, rep)
    if p is not None and p.n_ticks < 2:
        rep.errors.append(f"{log.path}: fewer than two ticks of data")
        return None
    return p


def produce(log: FileLog, p: Plan, tmap: TopicMap, robot: RobotSpec, rate_hz: float, sink: Sink,
            chunk_ticks: int | None = None) -> None:
    """Pass 2: the run table to ``sink`` in chunks of ``chunk_ticks`` ticks (None: one chunk).
    A log held in memory is merged once, at the end; a streamed one every ``DRAIN_ROWS`` rows."""
    prod = Producer(p, tmap, robot, rate_hz, chunk_ticks or p.n_ticks, sink, None if log.kept else DRAIN_ROWS)
    log.read(prod.on_part)
    log.release()   # a replayed log's parts now live in the buffers only
    prod.drain(final=True)
