"""The log path of the ingest engine: scan, plan, chunk producer (design §5, contract 1).

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

import re
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Protocol

import numpy as np
import pandas as pd

from terrainml.io import cdr, t265
from terrainml.io.ingest.report import IngestReport
from terrainml.io.ingest.signals import Signal, SourceFacts, assemble, joint_columns, last_hole_s, signals_for
from terrainml.io.readers import ReadResult, log_size, read_bag, read_mcap
from terrainml.io.ingest.resample import _EPS, clean_times, gap_threshold_s
from terrainml.io.topicmap import Source, TopicMap
from terrainml.robot import RobotSpec, check_wheel_count

DRAIN_ROWS = 5_000            # decoded rows held before they are merged (scan, streamed produce)
_JOINT_FIELDS = ("position", "velocity", "effort")
_NOT_NONFINITE = ("t_ns", "orientation", "cov0", "names")
_IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])
OnPart = Callable[[str, dict], None]


# ----------------------------------------------------------------------------- logs
def _wanted_for(tmap: TopicMap, topics: set[str] | None = None):
    """The reader's ``wanted(topic, type) -> decode kind`` for a topic map (only ``topics`` when
    given), and the dict it fills with mapped topics whose type does not match."""
    by_topic = tmap.by_topic()
    mismatched: dict[str, str] = {}

    def wanted(topic: str, type_name: str) -> str | None:
        src = by_topic.get(topic)
        if src is None or (topics is not None and topic not in topics):
            return None
        if (src.type and type_name != src.type) or cdr.KIND_OF_TYPE.get(type_name) != src.decode_kind:
            mismatched[topic] = type_name
            return None
        return src.decode_kind

    return wanted, mismatched


class FileLog:
    """A log re-read from disk on every pass: memory bounded by one MCAP chunk (``ingest --out``)."""

    kept = False   # decoded parts are not held between passes

    def __init__(self, path: Path, fmt: str, tmap: TopicMap, progress=None, passes: int = 2):
        self.path, self.fmt, self.tmap, self.progress = path, fmt, tmap, progress
        self.size = max(log_size(path), 1)
        self.passes, self.done = passes, 0
        self.validate_crcs = True
        self.mismatched: dict[str, str] = {}

    def release(self) -> None:
        """Nothing is kept between passes."""

    def read(self, on_part: OnPart, topics: set[str] | None = None) -> ReadResult:
        """One pass over the file (only ``topics`` decoded when given); progress spans all passes."""
        wanted, mismatched = _wanted_for(self.tmap, topics)
        offset = min(self.done, self.passes - 1) * self.size
        prog = None if self.progress is None else \
            (lambda done, total: self.progress(offset + done, self.passes * self.size))
        hdr = self.tmap.stamp == "header"
        if self.fmt == "mcap":
            res = read_mcap(self.path, wanted, use_header_stamp=hdr, progress=prog, on_part=on_part,
                            validate_crcs=self.validate_crcs)
        else:
            res = read_bag(self.path, wanted, use_header_stamp=hdr, progress=prog, on_part=on_part)
        if topics is None:
            self.done += 1
            if self.done == 1:
                self.mismatched = mismatched
                # every chunk passed its CRC in the first pass: later reads skip the check (same bytes)
                self.validate_crcs = res.corrupt_chunks > 0
        return res


class MemoryLog(FileLog):
    """A log read once, its decoded parts kept and replayed by later passes (``load_run``)."""

    kept = True

    def __init__(self, path: Path, fmt: str, tmap: TopicMap, progress=None):
        super().__init__(path, fmt, tmap, progress, passes=1)
        self.parts: list[tuple[str, dict]] | None = None

    def read(self, on_part: OnPart, topics: set[str] | None = None) -> ReadResult | None:
        if self.parts is None:
            self.parts = []
            return super().read(lambda topic, p: (self.parts.append((topic, p)), on_part(topic, p)))
        for topic, p in self.parts:
            if topics is None or topic in topics:
                on_part(topic, p)
        return None

    def release(self) -> None:
        self.parts = []


# ----------------------------------------------------------------------------- scan
@dataclass
class Series:
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
        dd = np.diff(t, prepend=t[0] if self.last is None else self.last)
        new = dd != 0
        if self.last is None:
            new[0] = True
        back = int(np.count_nonzero(dd < 0))
        self.out_of_order += back
        self.in_order &= back == 0
        if self.in_order:
            self.duplicates += int(np.count_nonzero(~new))
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
        return 2.0 * base if med is None else 2.0 * max(base, med * 1e-9)


@dataclass
class TopicScan:
    src: Source
    rows: int = 0
    max_ns: int | None = None       # running max (lateness)
    lateness_ns: int = 0
    series: Series | None = None    # whole topic (non-joint kinds)
    groups: dict = field(default_factory=dict)        # joint: names -> Series
    joint_series: dict = field(default_factory=dict)  # joint: joint name -> Series
    nonfinite: int = 0
    patterns: dict = field(default_factory=dict)      # joint: names -> bincount of non-finite field patterns
    any_finite: dict = field(default_factory=dict)    # joint: names -> [bool] * 3
    first_row: dict | None = None
    imu_all_identity: bool = True
    imu_all_zero: bool = True
    cam_best: tuple | None = None                     # (stamp, raw yaw) of the first valid pose
    cam_bad: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))

    @property
    def kind(self) -> str:
        return self.src.kind

    def all_series(self) -> list[Series]:
        return [self.series] if self.series else list(self.groups.values()) + list(self.joint_series.values())

    def nonfinite_total(self) -> int:
        """Messages with a NaN/Inf field (joint_state: only fields that are ever finite count)."""
        if self.kind != "joint_state":
            return self.nonfinite
        total = 0
        for names, pat in self.patterns.items():
            mask = sum(1 << b for b in range(3) if self.any_finite[names][b])
            total += int(sum(pat[c] for c in range(8) if c & mask))
        return total


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


class Scan:
    """Pass 1: constant-size facts of every mapped topic (``on_part`` consumer)."""

    def __init__(self, tmap: TopicMap, robot: RobotSpec, rate_hz: float, drain_rows: int | None = DRAIN_ROWS):
        self.by_topic = tmap.by_topic()
        self.drain_rows = drain_rows   # None: every topic reduced in one batch (a log held in memory)
        self.base_ns = 1e9 / rate_hz
        self.topics: dict[str, TopicScan] = {}
        self.pending: dict[str, list] = {}
        self.pending_rows = 0
        self.all_max: int | None = None
        self.cross_late = 0
        self.joint_cols = {s.topic: joint_columns(s, robot.n_wheels) for s in tmap.sources
                           if s.kind == "joint_state"}

    def on_part(self, topic: str, part: dict) -> None:
        t = part["t_ns"]
        n = len(t)
        if n == 0:
            return
        if topic not in self.topics:
            src = self.by_topic[topic]
            self.topics[topic] = TopicScan(src, series=None if src.kind == "joint_state" else Series(self.base_ns))
        lo, hi = (int(t[0]), int(t[0])) if n == 1 else (int(t.min()), int(t.max()))
        if self.all_max is not None:
            self.cross_late = max(self.cross_late, self.all_max - lo)
        self.all_max = hi if self.all_max is None else max(self.all_max, hi)
        self.pending.setdefault(topic, []).append(part)
        self.pending_rows += n
        if self.drain_rows is not None and self.pending_rows >= self.drain_rows:
            self.drain()

    def drain(self) -> None:
        for topic, parts in self.pending.items():
            self._topic_batch(self.topics[topic], parts)
        self.pending = {}
        self.pending_rows = 0

    def _topic_batch(self, ts: TopicScan, parts: list[dict]) -> None:
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
        elif ts.kind == "t265_odometry":   # in slices: once a pose is found, later stamps are skipped
            for i in range(0, len(new), DRAIN_ROWS):
                self._first_pose(ts, {k: v[i:i + DRAIN_ROWS] for k, v in part.items() if isinstance(v, np.ndarray)})

    @staticmethod
    def _first_pose(ts: TopicScan, part: dict) -> None:
        """Raw yaw of the first valid T265 pose in time order (duplicate stamps: first in file order)."""
        if ts.cam_best is not None and int(part["t_ns"].min()) >= ts.cam_best[0]:
            return  # nothing earlier than the pose already found
        yaw = t265.t265_odometry_to_body(part["position"], part["orientation"], part["linear"],
                                         part["angular"], positions=False)["yaw_raw_rad"]
        uniq, first = np.unique(part["t_ns"], return_index=True)
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

    def _joint_batch(self, ts: TopicScan, parts: list[dict]) -> None:
        wanted = {c.joint for c in self.joint_cols[ts.src.topic]}
        for run in _runs_by_names(parts):
            names = run["names"]
            g = ts.groups.get(names)
            if g is None:
                g = ts.groups[names] = Series(self.base_ns)
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
                ts.joint_series.setdefault(j, Series(self.base_ns)).add(run["t_ns"])

    @property
    def t0_ns(self) -> int | None:
        mins = [s.min_ns for ts in self.topics.values()
                for s in ([ts.series] if ts.series else list(ts.groups.values())) if s.min_ns is not None]
        return min(mins) if mins else None

    @property
    def lateness_all_ns(self) -> int:
        return max([self.cross_late] + [ts.lateness_ns for ts in self.topics.values()])

    def allow_cross_lateness(self, late_ns: int) -> None:
        """Let any topic lag the latest stamp of all topics by at least ``late_ns`` (ns) before its
        ticks are decided without it (a live stream's reorder bound; the scan only ever raises it)."""
        self.cross_late = max(self.cross_late, int(late_ns))

    @contextmanager
    def cross_lateness(self, late_ns: int) -> Iterator[None]:
        """Within the block, the lag allowed between topics is ``late_ns`` (ns); restored after."""
        saved, self.cross_late = self.cross_late, int(late_ns)
        try:
            yield
        finally:
            self.cross_late = saved


# ----------------------------------------------------------------------------- plan
@dataclass
class Buffer:
    """Sorted, de-duplicated samples of one source (a topic, or one joint of a joint_state topic)
    not yet behind every emitted chunk."""

    topic: str
    joint: str | None
    signals: list[Signal]             # templates: column, method, gap threshold (no samples)
    need_gap_s: float                 # how far an unseen sample must be for every tick to be decided
    fields: list[str] = field(default_factory=list)   # joint: the message field of each signal
    data: dict = field(default_factory=dict)
    pending: list = field(default_factory=list)

    def merge(self) -> None:
        if not self.pending:
            return
        cat = _concat(([self.data] if self.data else []) + self.pending)
        self.pending = []
        order, _, _ = clean_times(cat["t_ns"])
        if len(order) == len(cat["t_ns"]) and np.all(order == np.arange(len(order))):
            self.data = cat
        else:
            self.data = {k: (v[order] if isinstance(v, np.ndarray) else v) for k, v in cat.items()}

    def t_ns(self) -> np.ndarray:
        return self.data.get("t_ns", np.zeros(0, np.int64))


@dataclass
class Plan:
    """What the scan decided: the time origin, grid length, and a buffer per source (column order)."""

    t0_ns: int
    n_ticks: int
    buffers: list[Buffer]
    facts: dict[str, SourceFacts]          # non-joint topics: whole-log facts for signals_for
    scan: Scan

    def emptied(self, n_ticks: int) -> Plan:
        """The same sources, column templates and gap thresholds, with empty buffers and a grid
        of ``n_ticks`` ticks (a new live timeline)."""
        bufs = [Buffer(b.topic, b.joint, b.signals, b.need_gap_s, list(b.fields)) for b in self.buffers]
        return Plan(self.t0_ns, n_ticks, bufs, self.facts, self.scan)


def _need_gap(signals: list[Signal]) -> float:
    """How far past a chunk an unseen sample can still change it: the gap threshold of signals that
    look at the next sample (interpolated ones, and a regular label stream's hole rule)."""
    return max([s.max_gap_s for s in signals if (s.method != "previous" or s.period_s is not None)
                and np.isfinite(s.max_gap_s)] + [0.0])


def label_period_s(series: Series, rate_hz: float) -> float | None:
    """The period of a regular label stream, None when it is published on change (or damaged).

    Regular: at least three intervals and 75 % of them within half a period of the median
    (``max(base period, median interval)``); a stream of labels sent only when the terrain
    changes has no period, and its long intervals are no holes.
    """
    if not series.in_order or series.n_le + sum(len(g) for g in series.gt) < 3:
        return None
    period = series.gap_s(rate_hz) / 2.0
    d = np.concatenate(series.gt) * 1e-9 if series.gt else np.zeros(0)
    near = np.count_nonzero(np.abs(d - period) <= 0.5 * period)
    if series.n_le and series.max_le * 1e-9 >= 0.5 * period:
        near += series.n_le
    return period if near >= 0.75 * (series.n_le + len(d)) else None


def _unsorted_gaps(log: FileLog, scan: Scan, rate_hz: float, t0: int) -> tuple[dict, dict]:
    """Exact gap thresholds and duplicate counts of series whose stamps are out of order: one more
    pass decoding only their topics (holds those topics' stamps, 8 bytes each)."""
    todo = {topic for topic, ts in scan.topics.items() if any(not s.in_order for s in ts.all_series())}
    if not todo:
        return {}, {}
    stamps: dict[tuple, list] = {}

    def on_part(topic: str, part: dict) -> None:
        if scan.topics[topic].kind == "joint_state":
            stamps.setdefault((topic, "names", part["names"]), []).append(part["t_ns"])
            for j in {c.joint for c in scan.joint_cols[topic]}.intersection(part["names"]):
                stamps.setdefault((topic, "joint", j), []).append(part["t_ns"])
        else:
            stamps.setdefault((topic, "topic", None), []).append(part["t_ns"])

    log.read(on_part, todo)
    gaps, dups = {}, {}
    for (topic, what, name), ts_list in stamps.items():
        t = np.concatenate(ts_list)
        order, _, dup = clean_times(t)
        gap = gap_threshold_s((t[order] - t0) * 1e-9, rate_hz)
        key = topic if what == "topic" else (topic, name)
        if what != "joint":
            dups[key] = dup
        if what != "names":
            gaps[key] = gap
    return gaps, dups


def _topic_counts(topic: str, ts: TopicScan, extra_dups: dict, d: dict[str, Any]) -> None:
    if ts.kind == "joint_state":
        d["out_of_order"] = sum(g.out_of_order for g in ts.groups.values())
        d["duplicates"] = sum(extra_dups.get((topic, names), g.duplicates) for names, g in ts.groups.items())
    else:
        d["out_of_order"] = ts.series.out_of_order
        d["duplicates"] = extra_dups.get(topic, ts.series.duplicates)


def _log_wheels(src: Source, names: set[str]) -> int:
    """Wheels a joint_state topic has: the largest ``i`` of joint names matching the topic map's
    ``{i}`` joint templates (0 when none match)."""
    found = [0]
    for spec in src.columns.values():
        joint = spec.get("joint", "")
        if "{i}" in joint:
            pattern = re.compile("^" + re.escape(joint).replace(re.escape("{i}"), r"(\d+)") + "$")
            found += [int(m.group(1)) for m in map(pattern.match, names) if m]
    return max(found)


def plan(scan: Scan, log: FileLog, tmap: TopicMap, robot: RobotSpec, rate_hz: float,
         rep: IngestReport) -> Plan | None:
    """After the scan: report counts and warnings, per-source gap thresholds and column lists, the
    grid length. None (an error in ``rep``) when no mapped topic had a readable message."""
    path = log.path
    t0 = scan.t0_ns
    if t0 is None:
        rep.errors.append(f"{path}: no readable message on any mapped topic "
                          f"({', '.join(s.topic for s in tmap.sources)}); `terrainml inspect` lists the "
                          "log's topics, `--topics MAP.yaml` maps them")
        return None
    for topic, ts in scan.topics.items():   # a wheel count that differs from the spec is refused
        if ts.kind == "joint_state":
            n_log = _log_wheels(ts.src, {n for names in ts.groups for n in names})
            if n_log:
                check_wheel_count(robot, n_log, path)
    extra_gaps, extra_dups = _unsorted_gaps(log, scan, rate_hz, t0)
    buffers: list[Buffer] = []
    facts: dict[str, SourceFacts] = {}
    t_end = 0.0
    for topic, ts in scan.topics.items():
        d = rep.topics[topic]
        _topic_counts(topic, ts, extra_dups, d)
        k = ts.nonfinite_total()
        if k:
            d["non_finite"] = d.get("non_finite", 0) + k
            rep.warnings.append(f"{path}: topic {topic}: {k} message(s) with NaN/Inf fields (ticks marked invalid)")
        if ts.kind == "joint_state":
            per_joint: dict[str, Buffer] = {}
            for c in scan.joint_cols[topic]:
                s = ts.joint_series.get(c.joint)
                if s is None:
                    rep.warnings.append(f"{rep.source}: topic {topic}: no joint '{c.joint}' for column {c.column}")
                    continue
                gap = np.inf if c.column.startswith("gt_state") else \
                    extra_gaps.get((topic, c.joint), s.gap_s(rate_hz) if s.in_order else None)
                buf = per_joint.setdefault(c.joint, Buffer(topic, c.joint, [], 0.0))
                buf.signals.append(Signal(c.column, np.zeros(0), np.zeros(0), c.method, gap))
                buf.fields.append(c.field)
                t_end = max(t_end, (s.max_ns - t0) * 1e-9)
            buffers += per_joint.values()
        else:
            f = facts[topic] = SourceFacts(
                gap_s=ts.series.gap_s(rate_hz) if ts.series.in_order else extra_gaps.get(topic),
                imu_orientation=not (ts.imu_all_identity or ts.imu_all_zero),
                cam_yaw0_rad=None if ts.cam_best is None else ts.cam_best[1],
                label_period_s=label_period_s(ts.series, rate_hz) if ts.kind == "label" else None)
            first = ts.first_row
            tmpl = signals_for(ts.src, first, (first["t_ns"] - t0) * 1e-9, robot, tmap, f)
            if tmpl:
                buffers.append(Buffer(topic, None, tmpl, 0.0))
                t_end = max(t_end, (ts.series.max_ns - t0) * 1e-9)
        if d.get("out_of_order") or d.get("duplicates"):
            rep.warnings.append(f"{path}: topic {topic}: {d['out_of_order']} out-of-order and "
                                f"{d['duplicates']} duplicate timestamp(s) (sorted, duplicates dropped)")
    for buf in buffers:
        buf.need_gap_s = _need_gap(buf.signals)
    n_ticks = int(np.floor(t_end * rate_hz + 1e-6)) + 1 if buffers else 0
    return Plan(t0, n_ticks, buffers, facts, scan)


# ----------------------------------------------------------------------------- produce
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
