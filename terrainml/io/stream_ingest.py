"""Bounded-memory ingest: a ROS 2 MCAP or ROS 1 bag straight to a Parquet run table, in time chunks.

``ingest_to_parquet(LOG, OUT)`` (behind ``terrainml ingest LOG --out RUN.parquet``) writes the same
table as ``load_run(LOG).table`` followed by ``write_run_parquet`` (equal within float rounding,
``{group}_valid`` columns included, SYSTEM §5 metadata included), but its peak memory does not grow
with the length of the log: the table is produced ``chunk_s`` seconds at a time and appended to the
Parquet file as one row group per chunk (``pyarrow.parquet.ParquetWriter``).

Two passes over the file (both streaming, the reader never holds more than one MCAP chunk):

1. **scan** -- every mapped message is decoded and reduced at once to constant-size facts: the time
   origin (first stamp), the end of the grid, per-topic counts (decoded, corrupt, skipped,
   out-of-order, duplicate, non-finite), the first valid T265 pose (yaw zeroing), whether the IMU
   ever publishes an orientation, which joints exist, how late a message can arrive relative to
   the ones before it (``lateness``, per topic and over all topics), and the gap threshold
   ``2 * max(base period, median source period)`` of every source. The median is exact with
   O(1) memory for sources at or above the base rate: positive stamp differences at or below the
   base period are only counted, larger ones kept (so a slower source costs 8 bytes per message).
   A source whose stamps are out of order gets one extra streaming pass over that topic alone
   (damaged logs only) to sort its stamps.
2. **produce** -- messages are decoded again and merged into small per-source buffers, sorted,
   duplicates dropped (first in file order kept, as in ``load_run``). A chunk of base-rate ticks
   ``[ga, gb]`` is resampled as soon as every source is *settled* past ``gb``: the source's
   sample after ``gb`` is known and no earlier one can still arrive (the lateness bound), or no
   unseen sample can bracket a tick of the chunk within the gap threshold, or the source is
   exhausted. Each source slice holds the last sample at or before ``ga`` and the first after
   ``gb``, so interpolation, sample-and-hold and the gap rule see exactly what they see on the
   whole log; only the buffers between the chunk and the settle frontier are in memory.

Departures from ``load_run`` (edge cases of damaged logs, documented): the non-finite count and
the IMU "orientation never set" test are taken before duplicate stamps of an out-of-order topic are
dropped; a joint present in several joint-name sets of one topic breaks ties between equal stamps
by file order (``load_run``: by name set). CSV and Parquet inputs are tables already and go through
``load_run`` (not bounded).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pandas as pd

from terrainml.io import t265
from terrainml.io.ingest import (IngestReport, _assemble, _no_message_error, _open_input, _read_log,
                                 _report_read, _run_metadata, _Signal, _signals_for, _wanted_for, _expand,
                                 _PREVIOUS_COLUMNS, load_run)
from terrainml.io.readers import LogReadError
from terrainml.io.resample import _EPS, clean_times, gap_threshold_s
from terrainml.io.topicmap import Source, TopicMap, TopicMapError, load_topic_map
from terrainml.robot import RobotSpec
from terrainml.schema import (DEFAULT_RATE_HZ, METADATA_KEY, VALID_GROUPS, SchemaError, validate_run_table,
                              write_run_parquet)

DEFAULT_CHUNK_S = 30.0
DRAIN_ROWS = 5_000            # decoded rows held before they are merged into the source buffers
_JOINT_FIELDS = ("position", "velocity", "effort")
_NOT_NONFINITE = ("t_ns", "orientation", "cov0", "names")
_IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])


# ----------------------------------------------------------------------------- pass-1 statistics
@dataclass
class _Series:
    """Constant-memory facts of one stamp series in file order (a topic, a joint, a name set)."""

    base_ns: float
    n: int = 0
    last: int | None = None
    min_ns: int | None = None
    max_ns: int | None = None
    in_order: bool = True
    out_of_order: int = 0
    duplicates: int = 0          # exact while in_order
    n_le: int = 0                # positive differences <= base period
    max_le: int = 0
    gt: list = field(default_factory=list)   # positive differences > base period (ns)

    def add(self, t: np.ndarray) -> np.ndarray:
        """Feed stamps (file order); returns the mask of rows that do not repeat the previous stamp."""
        n = len(t)
        if n == 0:
            return np.zeros(0, bool)
        t = np.asarray(t, np.int64)
        if self.last is None:
            dd = np.diff(t)
            new = np.ones(n, bool)
            new[1:] = dd != 0
        else:
            dd = np.diff(t, prepend=self.last)
            new = dd != 0
        back = int(np.count_nonzero(dd < 0))
        self.out_of_order += back
        if back:
            self.in_order = False
        if self.in_order:
            self.duplicates += int(np.count_nonzero(dd == 0))
            pos = dd[dd > 0]
            le = pos <= self.base_ns
            k = int(np.count_nonzero(le))
            if k:
                self.n_le += k
                self.max_le = max(self.max_le, int(pos[le].max()))
            if k < len(pos):
                self.gt.append(pos[~le])
        self.n += n
        lo, hi = int(t.min()), int(t.max())
        self.min_ns = lo if self.min_ns is None else min(self.min_ns, lo)
        self.max_ns = hi if self.max_ns is None else max(self.max_ns, hi)
        self.last = int(t[-1])
        return new

    def gap_s(self, rate_hz: float) -> float:
        """``gap_threshold_s`` of the sorted unique series (only valid while ``in_order``)."""
        base = 1.0 / rate_hz
        gts = np.sort(np.concatenate(self.gt)) if self.gt else np.zeros(0, np.int64)
        m = self.n_le + len(gts)            # number of unique stamps - 1
        if m == 0:
            return 2.0 * base

        def value(r: int) -> float | None:  # r-th smallest positive difference, None if <= base (not kept)
            if r < self.n_le:
                return float(self.max_le) if r == self.n_le - 1 else None
            return float(gts[r - self.n_le])

        if m % 2:
            med = value(m // 2)
        else:
            a, b = value(m // 2 - 1), value(m // 2)
            med = None if a is None or b is None else 0.5 * (a + b)
        if med is None:
            return 2.0 * base
        return 2.0 * max(base, med * 1e-9)


@dataclass
class _TopicScan:
    src: Source
    kind: str
    rows: int = 0
    max_ns: int | None = None       # running max (lateness)
    lateness_ns: int = 0
    series: _Series | None = None   # whole topic (non-joint kinds)
    groups: dict = field(default_factory=dict)       # joint: names -> _Series
    joint_series: dict = field(default_factory=dict)  # joint: joint name -> _Series
    nonfinite: int = 0
    patterns: dict = field(default_factory=dict)     # joint: names -> bincount of non-finite field patterns
    any_finite: dict = field(default_factory=dict)   # joint: names -> [bool] * 3
    first_row: dict | None = None
    imu_all_identity: bool = True
    imu_all_zero: bool = True
    cam_best: tuple | None = None                    # (stamp, raw yaw) of the first valid pose
    cam_bad: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))


def _concat(parts: list[dict]) -> dict:
    if len(parts) == 1:
        return parts[0]
    return {k: (np.concatenate([p[k] for p in parts]) if isinstance(parts[0][k], np.ndarray) else parts[0][k])
            for k in parts[0]}


def _runs_by_names(parts: list[dict]) -> list[dict]:
    """Consecutive joint_state parts with the same joint names joined (file order kept)."""
    out, run = [], []
    for p in parts:
        if run and p["names"] != run[0]["names"]:
            out.append(_concat(run))
            run = []
        run.append(p)
    if run:
        out.append(_concat(run))
    return out


def _joint_columns(src: Source, robot: RobotSpec) -> list[tuple[str, str, str, str]]:
    """(column, joint, field, method) of a joint_state source, in ``load_run``'s order."""
    cols = []
    for template, spec in src.columns.items():
        for i in range(1, robot.n_wheels + 1) if "{i}" in template else [None]:
            col = _expand(template, i) if i else template
            joint = _expand(spec["joint"], i) if i else spec["joint"]
            method = spec.get("resample", "previous" if col.endswith(_PREVIOUS_COLUMNS) else "linear")
            cols.append((col, joint, spec["field"], method))
    return cols


class _Scan:
    """Pass 1: constant-size facts of every mapped topic."""

    def __init__(self, tmap: TopicMap, robot: RobotSpec, rate_hz: float):
        self.by_topic = tmap.by_topic()
        self.robot, self.rate_hz = robot, rate_hz
        self.base_ns = 1e9 / rate_hz
        self.topics: dict[str, _TopicScan] = {}
        self.pending: dict[str, list] = {}
        self.pending_rows = 0
        self.all_max: int | None = None
        self.cross_late = 0
        self.joint_cols = {s.topic: _joint_columns(s, robot) for s in tmap.sources if s.kind == "joint_state"}

    def on_part(self, topic: str, part: dict) -> None:
        t = part["t_ns"]
        n = len(t)
        if n == 0:
            return
        if topic not in self.topics:
            src = self.by_topic[topic]
            ts = _TopicScan(src, src.kind)
            if src.kind != "joint_state":
                ts.series = _Series(self.base_ns)
            self.topics[topic] = ts
        lo, hi = (int(t[0]), int(t[0])) if n == 1 else (int(t.min()), int(t.max()))
        if self.all_max is not None:
            self.cross_late = max(self.cross_late, self.all_max - lo)
        self.all_max = hi if self.all_max is None else max(self.all_max, hi)
        self.pending.setdefault(topic, []).append(part)
        self.pending_rows += n
        if self.pending_rows >= DRAIN_ROWS:
            self.drain()

    def drain(self) -> None:
        for topic, parts in self.pending.items():
            if parts:
                self._topic_batch(self.topics[topic], parts)
        self.pending = {}
        self.pending_rows = 0

    def _topic_batch(self, ts: _TopicScan, parts: list[dict]) -> None:
        t_all = np.concatenate([p["t_ns"] for p in parts])
        prev = ts.max_ns if ts.max_ns is not None else int(t_all[0])
        cm = np.maximum.accumulate(np.concatenate([[prev], t_all]))
        ts.lateness_ns = max(ts.lateness_ns, int((cm[:-1] - t_all).max()))
        ts.max_ns = int(cm[-1])
        ts.rows += len(t_all)
        if ts.kind == "joint_state":
            self._joint_batch(ts, parts)
            return
        part = _concat(parts)
        if ts.first_row is None:
            ts.first_row = {k: (v[:1].copy() if isinstance(v, np.ndarray) else v) for k, v in part.items()}
        new = ts.series.add(part["t_ns"])
        bad = np.zeros(len(new), bool)
        for k, v in part.items():
            if k not in _NOT_NONFINITE and isinstance(v, np.ndarray):
                bad |= ~np.isfinite(v.reshape(len(v), -1)).all(axis=1)
        ts.nonfinite += int(np.count_nonzero(bad & new))
        if ts.kind == "imu":
            qf = np.nan_to_num(part["orientation"])
            ts.imu_all_identity &= bool(np.allclose(qf, _IDENTITY))
            ts.imu_all_zero &= bool(np.allclose(qf, 0.0))
        elif ts.kind == "t265_odometry":
            self._first_pose(ts, part)

    @staticmethod
    def _first_pose(ts: _TopicScan, part: dict) -> None:
        """Raw yaw of the first valid T265 pose in time order (duplicate stamps: first in file order)."""
        if ts.cam_best is not None and int(part["t_ns"].min()) >= ts.cam_best[0]:
            return  # nothing earlier than the pose already found
        yaw = t265.t265_odometry_to_body(part["position"], part["orientation"], part["linear"],
                                         part["angular"])["yaw_raw_rad"]
        t = part["t_ns"]
        uniq, first = np.unique(t, return_index=True)
        ok = np.isfinite(yaw[first])
        fresh = ~np.isin(uniq, ts.cam_bad)
        if ts.cam_best is not None:
            fresh &= uniq < ts.cam_best[0]
        cand = np.flatnonzero(ok & fresh)
        if cand.size:
            k = int(cand[0])  # uniq is sorted: the smallest stamp
            ts.cam_best = (int(uniq[k]), float(yaw[first[k]]))
        bad = uniq[~ok & fresh]
        if bad.size:
            ts.cam_bad = np.union1d(ts.cam_bad, bad)
        if ts.cam_best is not None and ts.cam_bad.size:
            ts.cam_bad = ts.cam_bad[ts.cam_bad < ts.cam_best[0]]

    def _joint_batch(self, ts: _TopicScan, parts: list[dict]) -> None:
        wanted = {j for _, j, _, _ in self.joint_cols[ts.src.topic]}
        for run in _runs_by_names(parts):
            names = run["names"]
            g = ts.groups.get(names)
            if g is None:
                g = ts.groups[names] = _Series(self.base_ns)
                ts.patterns[names] = np.zeros(8, np.int64)
                ts.any_finite[names] = [False, False, False]
            new = g.add(run["t_ns"])
            code = np.zeros(len(new), np.int64)
            for b, f in enumerate(_JOINT_FIELDS):
                fin = np.isfinite(run[f])
                ts.any_finite[names][b] |= bool(fin.any())
                code |= (~fin.all(axis=1)).astype(np.int64) << b
            ts.patterns[names] += np.bincount(code[new], minlength=8)
            for j in wanted.intersection(names):
                s = ts.joint_series.get(j)
                if s is None:
                    s = ts.joint_series[j] = _Series(self.base_ns)
                s.add(run["t_ns"])

    def finish_nonfinite(self, ts: _TopicScan) -> int:
        if ts.kind != "joint_state":
            return ts.nonfinite
        total = 0
        for names, pat in ts.patterns.items():
            mask = sum(1 << b for b in range(3) if ts.any_finite[names][b])
            total += int(sum(pat[c] for c in range(8) if c & mask))
        return total

    @property
    def t0_ns(self) -> int | None:
        mins = [s.min_ns for ts in self.topics.values()
                for s in ([ts.series] if ts.series else list(ts.groups.values())) if s.min_ns is not None]
        return min(mins) if mins else None

    @property
    def lateness_all_ns(self) -> int:
        return max([self.cross_late] + [ts.lateness_ns for ts in self.topics.values()])


# ----------------------------------------------------------------------------- pass-2 buffers
@dataclass
class _Buffer:
    """Sorted, de-duplicated samples of one source not yet behind every emitted chunk."""

    topic: str
    columns: list                 # [(column, method, max_gap_s)] produced from this buffer
    need_gap_s: float             # how far an unseen sample must be for every tick to be decided
    data: dict = field(default_factory=dict)
    pending: list = field(default_factory=list)

    def merge(self) -> None:
        if not self.pending:
            return
        parts = ([self.data] if self.data else []) + self.pending
        self.pending = []
        cat = _concat(parts)
        order, _, _ = clean_times(cat["t_ns"])
        if len(order) == len(cat["t_ns"]) and np.all(order == np.arange(len(order))):
            self.data = cat
        else:
            self.data = {k: (v[order] if isinstance(v, np.ndarray) else v) for k, v in cat.items()}

    def t_ns(self) -> np.ndarray:
        return self.data.get("t_ns", np.zeros(0, np.int64))


class _Producer:
    """Pass 2: merges decoded parts into per-source buffers and emits settled chunks of ticks."""

    def __init__(self, scan: _Scan, info: dict, tmap: TopicMap, robot: RobotSpec, rate_hz: float,
                 chunk_ticks: int, emit: Callable[[pd.DataFrame], None], rep: IngestReport):
        self.scan, self.info, self.tmap, self.robot, self.rate_hz = scan, info, tmap, robot, rate_hz
        self.t0 = info["t0_ns"]
        self.n_ticks, self.chunk_ticks, self.emit, self.rep = info["n_ticks"], chunk_ticks, emit, rep
        self.next_tick = 0
        self.rows_seen: dict[str, int] = {}
        self.topic_max: dict[str, int] = {}
        self.all_max: int | None = None
        self.pending_rows = 0
        self.buffers: dict[Any, _Buffer] = {}
        self.order = info["order"]          # (topic, buffer key) in load_run's column order
        for topic, key in self.order:
            self.buffers[key] = info["buffers"][key]

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
        kind = self.scan.topics[topic].kind
        if kind == "joint_state":
            for col_joint in self.info["joints_of"].get(topic, ()):
                if col_joint in part["names"]:
                    k = part["names"].index(col_joint)
                    self.buffers[(topic, col_joint)].pending.append(
                        {"t_ns": t, **{f: part[f][:, k] for f in _JOINT_FIELDS}})
        elif topic in self.buffers:
            self.buffers[topic].pending.append(part)
        self.pending_rows += n
        if self.pending_rows >= DRAIN_ROWS:
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

    def _settled(self, buf: _Buffer, gb: float, frontier_ns: float) -> bool:
        """Can ticks up to ``gb`` be resampled from this buffer exactly as on the whole log?"""
        if frontier_ns == np.inf:
            return True
        t = buf.t_ns()
        if len(t):  # the sample after gb is known and nothing earlier can still arrive
            j = int(np.searchsorted(_ts(t, self.t0), gb + _EPS, side="right"))
            if j < len(t) and t[j] <= frontier_ns:
                return True
        # any unseen sample is too far away to bracket a tick of the chunk within the gap rule
        return (frontier_ns - self.t0) * 1e-9 > gb + buf.need_gap_s + 1e-6

    def drain(self, final: bool) -> None:
        for buf in self.buffers.values():
            buf.merge()
        self.pending_rows = 0
        fronts = {topic: self._frontier_ns(topic, final) for topic in self.scan.topics}
        while self.next_tick < self.n_ticks:
            a = self.next_tick
            b = min(a + self.chunk_ticks, self.n_ticks)
            gb = (b - 1) / self.rate_hz
            if not all(self._settled(buf, gb, fronts[buf.topic]) for buf in self.buffers.values()):
                return
            self._emit_chunk(a, b)
            self.next_tick = b

    # -- output
    def _emit_chunk(self, a: int, b: int) -> None:
        grid = np.arange(a, b) / self.rate_hz
        ga, gb = grid[0], grid[-1]
        ga_next = b / self.rate_hz
        signals: list[_Signal] = []
        for topic, key in self.order:
            buf = self.buffers[key]
            t = buf.t_ns()
            ts = _ts(t, self.t0)
            if len(ts):
                lo = max(int(np.searchsorted(ts, ga + _EPS, side="right")) - 1, 0)
                hi = min(int(np.searchsorted(ts, gb + _EPS, side="right")), len(ts) - 1)
                sl = slice(lo, hi + 1)
            else:
                sl = slice(0, 0)
            signals += self._signals(topic, key, buf, sl, ts[sl])
            if len(ts):  # keep from the last sample at or before the next chunk's first tick
                keep = max(int(np.searchsorted(ts, ga_next + _EPS, side="right")) - 1, 0)
                if keep:
                    buf.data = {k: (v[keep:] if isinstance(v, np.ndarray) else v) for k, v in buf.data.items()}
        df = _assemble(signals, grid, self.robot, self.rep)
        self.emit(df)

    def _signals(self, topic: str, key, buf: _Buffer, sl: slice, t_s: np.ndarray) -> list[_Signal]:
        ts = self.scan.topics[topic]
        if ts.kind == "joint_state":
            out = []
            for col, _joint, fld, method, gap in buf.columns:
                out.append(_Signal(col, t_s, buf.data[fld][sl] if len(t_s) else np.zeros(0), method, gap))
            return out
        if not len(t_s):
            return [_Signal(col, t_s, np.zeros(0), method, gap) for col, method, gap in buf.columns]
        part = {k: (v[sl] if isinstance(v, np.ndarray) else v) for k, v in buf.data.items()}
        return _signals_for(ts.src, part, t_s, self.robot, self.tmap, self.rate_hz, **self.info["kw"][topic])


def _ts(t_ns: np.ndarray, t0: int) -> np.ndarray:
    return (t_ns - t0) * 1e-9


# ----------------------------------------------------------------------------- orchestration
def _unsorted_pass(path: Path, fmt: str, tmap: TopicMap, scan: _Scan, rate_hz: float, t0: int,
                   progress=None) -> tuple[dict, dict]:
    """Exact gap thresholds and duplicate counts of series whose stamps are out of order: one more
    streaming pass decoding only their topics (holds those topics' stamps, 8 bytes each)."""
    todo = set()
    for topic, ts in scan.topics.items():
        sers = [ts.series] if ts.series else list(ts.groups.values()) + list(ts.joint_series.values())
        if any(not s.in_order for s in sers):
            todo.add(topic)
    if not todo:
        return {}, {}
    wanted_all, _ = _wanted_for(tmap)

    def wanted(topic: str, type_name: str) -> str | None:
        return wanted_all(topic, type_name) if topic in todo else None

    stamps: dict[Any, list] = {}

    def on_part(topic: str, part: dict) -> None:
        if scan.topics[topic].kind == "joint_state":
            stamps.setdefault((topic, "names", part["names"]), []).append(part["t_ns"])
            mapped = {j for _, j, _, _ in scan.joint_cols[topic]}
            for j in mapped.intersection(part["names"]):
                stamps.setdefault((topic, "joint", j), []).append(part["t_ns"])
        else:
            stamps.setdefault((topic, "topic", None), []).append(part["t_ns"])

    _read_log(path, fmt, tmap, wanted, progress, on_part)
    gaps, dups = {}, {}
    for (topic, what, name), ts_list in stamps.items():
        t = np.concatenate(ts_list)
        order, _, dup = clean_times(t)
        t_s = (t[order] - t0) * 1e-9
        if what == "topic":
            gaps[topic] = gap_threshold_s(t_s, rate_hz)
            dups[topic] = dup
        elif what == "names":
            dups[(topic, name)] = dup
        else:
            gaps[(topic, name)] = gap_threshold_s(t_s, rate_hz)
    return gaps, dups


def _plan(scan: _Scan, path: Path, fmt: str, tmap: TopicMap, robot: RobotSpec, rate_hz: float,
          rep: IngestReport, progress) -> dict | None:
    """After the scan: report counts and warnings (in ``load_run``'s order), per-source gap
    thresholds and column lists, the grid length."""
    t0 = scan.t0_ns
    if t0 is None:
        rep.errors.append(_no_message_error(path, tmap))
        return None
    extra_gaps, extra_dups = _unsorted_pass(path, fmt, tmap, scan, rate_hz, t0, progress)
    info: dict[str, Any] = {"t0_ns": t0, "buffers": {}, "order": [], "kw": {}, "joints_of": {}}
    t_end = 0.0
    for topic, ts in scan.topics.items():
        d = rep.topics[topic]
        src = ts.src
        if ts.kind == "joint_state":
            d["out_of_order"] = sum(g.out_of_order for g in ts.groups.values())
            d["duplicates"] = sum(extra_dups.get((topic, names), g.duplicates) for names, g in ts.groups.items())
        else:
            d["out_of_order"] = ts.series.out_of_order
            d["duplicates"] = extra_dups.get(topic, ts.series.duplicates)
        k = scan.finish_nonfinite(ts)
        if k:
            d["non_finite"] = d.get("non_finite", 0) + k
            rep.warnings.append(f"{path}: topic {topic}: {k} message(s) with NaN/Inf fields (ticks marked invalid)")
        if ts.kind == "joint_state":
            per_joint: dict[str, list] = {}
            for col, joint, fld, method in scan.joint_cols[topic]:
                s = ts.joint_series.get(joint)
                if s is None:
                    rep.warnings.append(f"{rep.source}: topic {src.topic}: no joint '{joint}' for column {col}")
                    continue
                gap = np.inf if col.startswith("gt_state") else \
                    extra_gaps.get((topic, joint), s.gap_s(rate_hz) if s.in_order else None)
                per_joint.setdefault(joint, []).append((col, joint, fld, method, gap))
                t_end = max(t_end, (s.max_ns - t0) * 1e-9)
            for joint, cols in per_joint.items():
                need = max([g for _, _, _, m, g in cols if m != "previous" and np.isfinite(g)] + [0.0])
                info["buffers"][(topic, joint)] = _Buffer(topic, cols, need)
                info["order"].append((topic, (topic, joint)))
            info["joints_of"][topic] = tuple(per_joint)
        else:
            gap = extra_gaps.get(topic) if not ts.series.in_order else ts.series.gap_s(rate_hz)
            kw: dict[str, Any] = {"gap_s": gap}
            if ts.kind == "imu":
                kw["imu_orientation"] = not (ts.imu_all_identity or ts.imu_all_zero)
            if ts.kind == "t265_odometry" and ts.cam_best is not None:
                kw["cam_yaw0_rad"] = ts.cam_best[1]
            info["kw"][topic] = kw
            first = ts.first_row
            tmpl = _signals_for(src, first, (first["t_ns"] - t0) * 1e-9, robot, tmap, rate_hz, **kw)
            cols = [(s.column, s.method, s.max_gap_s) for s in tmpl]
            if cols:
                need = max([g for _, m, g in cols if m != "previous" and np.isfinite(g)] + [0.0])
                info["buffers"][topic] = _Buffer(topic, cols, need)
                info["order"].append((topic, topic))
                t_end = max(t_end, (ts.series.max_ns - t0) * 1e-9)
        if d.get("out_of_order") or d.get("duplicates"):
            rep.warnings.append(f"{path}: topic {topic}: {d['out_of_order']} out-of-order and "
                                f"{d['duplicates']} duplicate timestamp(s) (sorted, duplicates dropped)")
    info["n_ticks"] = int(np.floor(t_end * rate_hz + 1e-6)) + 1 if info["order"] else 0
    return info


def ingest_to_parquet(path: str | Path, out: str | Path, *, robot: RobotSpec | str | Path | None = None,
                      topic_map: TopicMap | str | Path | dict | None = None, rate_hz: float = DEFAULT_RATE_HZ,
                      chunk_s: float = DEFAULT_CHUNK_S,
                      progress: Callable[[int, int], None] | None = None) -> IngestReport:
    """Ingest a log into a Parquet run table with memory bounded by ``chunk_s`` (not the log length).

    Parameters
    ----------
    path : ``.mcap`` (ROS 2) or ``.bag`` (ROS 1) streamed; ``.csv``/``.parquet`` via ``load_run``.
    out : output ``.parquet``; written only when a usable table resulted (else nothing is left).
    robot, topic_map, rate_hz : as :func:`terrainml.io.ingest.load_run`.
    chunk_s : seconds of base-rate ticks per chunk (one Parquet row group each).
    progress : optional ``(done, total)`` callback (two passes over the file's bytes).

    Returns
    -------
    IngestReport, as ``load_run(...).report`` (``rows``, ``span_s``, ``valid_fraction``,
    ``usable``, per-topic counts, warnings, errors). The file equals
    ``write_run_parquet(load_run(...).table, out)`` read back, within float rounding.
    """
    path, out = Path(path), Path(out)
    rep = IngestReport(source=str(path), rate_hz=float(rate_hz))
    path, robot_spec, ok = _open_input(path, robot, rate_hz, rep)
    if not ok:
        return rep
    fmt = rep.format
    if fmt not in ("mcap", "bag"):
        res = load_run(path, robot=robot_spec, topic_map=topic_map, rate_hz=rate_hz, progress=progress)
        if res.report.usable:
            write_run_parquet(res.table, out)
        return res.report
    if not (isinstance(chunk_s, (int, float)) and np.isfinite(chunk_s) and chunk_s > 0):
        rep.errors.append(f"chunk_s must be a positive number, got {chunk_s!r}")
        return rep
    try:
        tmap = load_topic_map(topic_map if topic_map is not None else ("default" if fmt == "mcap" else None))
        return _stream(path, out, fmt, robot_spec, tmap, float(rate_hz), float(chunk_s), rep, progress)
    except (LogReadError, TopicMapError, SchemaError) as exc:
        rep.errors.append(str(exc))
        return rep


def _stream(path: Path, out: Path, fmt: str, robot: RobotSpec, tmap: TopicMap, rate_hz: float, chunk_s: float,
            rep: IngestReport, progress) -> IngestReport:
    size = max(os.path.getsize(path), 1)

    def prog(offset: int):
        if progress is None:
            return None
        return lambda done, total: progress(offset + done, 2 * size)

    # pass 1: scan
    wanted, mismatched = _wanted_for(tmap)
    scan = _Scan(tmap, robot, rate_hz)
    res = _read_log(path, fmt, tmap, wanted, prog(0), scan.on_part)
    scan.drain()
    _report_read(path, res, tmap, mismatched, rep)
    info = _plan(scan, path, fmt, tmap, robot, rate_hz, rep, prog(0))
    if info is None:
        return rep
    if info["n_ticks"] < 2:
        rep.errors.append(f"{path}: fewer than two ticks of data")
        return rep
    run_id = path.stem
    meta = _run_metadata(path, robot, tmap, rate_hz, rep, run_id)

    # pass 2: produce
    import pyarrow as pa
    import pyarrow.parquet as pq

    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.part")
    state: dict[str, Any] = {"writer": None, "schema": None, "rows": 0, "last_t": 0.0,
                             "valid": {g: 0 for g in VALID_GROUPS}}

    def emit(df: pd.DataFrame) -> None:
        df["run_id"] = run_id
        if state["writer"] is None:  # every chunk has the same columns and dtypes: check the first,
            df = validate_run_table(df, robot.n_wheels, source=str(path))  # the Parquet schema the rest
            table = pa.Table.from_pandas(df, preserve_index=False)
            kv = dict(table.schema.metadata or {})
            kv[METADATA_KEY] = json.dumps(meta, default=str).encode()
            state["schema"] = table.schema.with_metadata(kv)
            state["writer"] = pq.ParquetWriter(tmp, state["schema"])
        schema = state["schema"]   # columns straight to Arrow (pandas' converter is ~2x slower per chunk)
        table = pa.Table.from_arrays([pa.array(df[f.name].to_numpy(dtype=object if pa.types.is_string(f.type)
                                                                     or pa.types.is_large_string(f.type) else None),
                                                type=f.type) for f in schema], schema=schema)
        state["writer"].write_table(table)
        state["rows"] += len(df)
        state["last_t"] = float(df["t_s"].iloc[-1])
        for g in VALID_GROUPS:
            if f"{g}_valid" in df:
                state["valid"][g] += int(df[f"{g}_valid"].sum())

    chunk_ticks = max(int(round(chunk_s * rate_hz)), 1)
    prod = _Producer(scan, info, tmap, robot, rate_hz, chunk_ticks, emit, rep)
    try:
        # every chunk passed its CRC in the scan: the second read skips the check (same bytes)
        _read_log(path, fmt, tmap, _wanted_for(tmap)[0], prog(size), prod.on_part,
                  validate_crcs=res.corrupt_chunks > 0)
        prod.drain(final=True)
    except BaseException:
        if state["writer"] is not None:
            state["writer"].close()
        tmp.unlink(missing_ok=True)
        raise
    if state["writer"] is not None:
        state["writer"].close()
    rows = state["rows"]
    rep.rows = rows
    rep.span_s = state["last_t"]
    rep.valid_fraction = {g: v / rows for g, v in state["valid"].items()} if rows else {}
    rep.usable = rows >= 2 and any(rep.valid_fraction.get(g, 0.0) > 0 for g in ("wheels", "imu", "cam"))
    if not rep.usable:
        rep.errors.append(f"{path}: no valid wheel, IMU or camera sample on the base grid")
        tmp.unlink(missing_ok=True)
        return rep
    os.replace(tmp, out)
    return rep
