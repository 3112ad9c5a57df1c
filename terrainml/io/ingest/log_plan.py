"""What the ingest engine decides after the scan: report counts and warnings, per-source columns
and gap thresholds, the grid length.

A joint_state topic whose wheel count (joint names matching the map's ``{i}`` templates) differs
from the robot spec's is refused (:func:`terrainml.robot.check_wheel_count`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from terrainml.io.ingest.log_scan import Scan, Series, TopicScan, concat_parts
from terrainml.io.ingest.log_sources import FileLog
from terrainml.io.ingest.ingest_report import IngestReport
from terrainml.io.ingest.resample import clean_times, gap_threshold_s
from terrainml.io.ingest.signals import Signal, SourceFacts, signals_for
from terrainml.io.topicmap import Source, TopicMap
from terrainml.robot import RobotSpec, check_wheel_count

__all__ = ["Buffer", "Plan", "label_period_s", "plan"]

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
        cat = concat_parts(([self.data] if self.data else []) + self.pending)
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
