"""Pass 1 of the ingest engine: every mapped message reduced at once to constant-size facts.

The facts: time origin, grid end, per-topic counts, the first valid T265 pose (yaw zeroing), whether
the IMU ever publishes an orientation, which joints exist, how late a message can arrive
(``lateness``) and each source's gap threshold ``2 * max(base period, median period)`` (exact in
O(1) memory for sources at or above the base rate; a slower one keeps its larger stamp
differences). A topic whose stamps are out of order gets one more pass over that topic alone
(damaged logs only, :mod:`terrainml.io.ingest.log_plan`).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from terrainml.io import t265
from terrainml.io.ingest.signals import joint_columns
from terrainml.io.topicmap import FIELDS as JOINT_FIELDS, Source, TopicMap
from terrainml.robot import RobotSpec

__all__ = ["DRAIN_ROWS", "Series", "TopicScan", "Scan", "concat_parts"]

DRAIN_ROWS = 5_000            # decoded rows held before they are merged (scan, streamed produce)
_NOT_NONFINITE = ("t_ns", "orientation", "cov0", "names")
_IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])


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


def concat_parts(parts: list[dict]) -> dict:
    if len(parts) == 1:
        return parts[0]
    return {k: (np.concatenate([p[k] for p in parts]) if isinstance(parts[0][k], np.ndarray) else parts[0][k])
            for k in parts[0]}


def _runs_by_names(parts: list[dict]) -> list[dict]:
    """Consecutive joint_state parts with the same joint names joined (file order kept)."""
    out, run = [], []
    for p in parts:
        if run and p["names"] != run[0]["names"]:
            out.append(concat_parts(run))
            run = []
        run.append(p)
    if run:
        out.append(concat_parts(run))
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
        part = concat_parts(parts)
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
            for b, f in enumerate(JOINT_FIELDS):
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
