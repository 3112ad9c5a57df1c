"""The ingest engine's produce step one tick at a time, for live streams (design §5).

:class:`~terrainml.io.ingest.logs.Producer` resamples chunks of ticks with numpy and builds a
DataFrame per chunk: right for a log (thousands of ticks a chunk), some 10 ms of CPU for a chunk of
one tick, which is what a live stream asks for at every base period. :class:`TickProducer` takes the
same :class:`~terrainml.io.ingest.logs.Plan` (the scan's time origin, gap thresholds, column
templates, IMU orientation, first T265 pose), the same settling test and the same rules, and
produces the same rows as sample dicts (python scalars, the columns of the samples a log source
yields, ``iter_table_samples``):

* each message is converted once, by :func:`~terrainml.io.ingest.signals.signals_for` (units,
  frames, IMU mount, T265 lever arm and yaw zeroing; a row-wise transform), in one batch per source
  and per emission, and kept in a per-source ring of plain floats (sorted stamps, duplicates
  dropped, first received kept);
* a tick is interpolated from the two bracketing samples of each source by
  :func:`~terrainml.io.ingest.resample.at_tick` -- :func:`~terrainml.io.ingest.resample.resample`'s
  rules in plain floats, because a numpy call per column costs more than the tick's budget -- and
  assembled with :func:`~terrainml.io.ingest.signals.assemble`'s column rules (fixed steering,
  absent columns, ``{group}_valid`` members, label holds never across a hole or a hole of the label
  stream, wheel-state names), taken from the same helpers.

``tests/io/test_ingest_ticks.py`` checks the rows against ``load_run``'s table column by column.
Two documented departures, both below 1e-9: an angle is unwrapped over the bracketing pair only
(the table unwraps a whole chunk, whose accumulated multiples of 2 pi round differently), and a
T265 stream without any valid pose in the plan zeroes its yaw per batch (no yaw then either way).
"""

from __future__ import annotations

import math
from bisect import bisect_left, bisect_right

import numpy as np

from terrainml.io.ingest.log_plan import Buffer, Plan
from terrainml.io.ingest.resample import _EPS, at_tick
from terrainml.io.ingest.signals import Signal, filled_columns, label_stream_stale, signals_for, validity_members
from terrainml.io.topicmap import TopicMap
from terrainml.robot import RobotSpec
from terrainml.schema import WHEEL_STATES, column_map, valid_column

_STATE_NAMES = list(WHEEL_STATES) + ["unknown"]


class _Ring:
    """One buffer's samples not yet behind every emitted tick: sorted unique stamps, one row of
    column values (and low-confidence flags) per stamp, converted lazily."""

    def __init__(self, buf: Buffer, t0_ns: int):
        self.buf, self.topic, self.t0 = buf, buf.topic, t0_ns
        self.t_ns: list[int] = []
        self.t_s: list[float] = []
        self.rows: list[tuple | None] = []       # per stamp: (values, flags); None until converted
        self.pending: list[dict] = []             # raw parts of a non-joint source (row picks)
        self.cols = [s.column for s in buf.signals]
        held = [c.startswith("gt_state") or c == "terrain" for c in self.cols]
        self.methods = ["previous" if h else s.method for s, h in zip(buf.signals, held)]
        self.no_flags = (None,) * len(self.cols)
        self.gaps = [math.inf if c == "terrain" else s.max_gap_s for c, s in zip(self.cols, buf.signals)]

    def add(self, part: dict) -> None:
        t = part["t_ns"]
        joint = self.buf.joint
        if joint is not None:
            if joint not in part["names"]:
                return
            k = part["names"].index(joint)
        keep = []
        for i in range(len(t)):
            ti = int(t[i])
            j = bisect_left(self.t_ns, ti)
            if j < len(self.t_ns) and self.t_ns[j] == ti:
                continue                          # a duplicate stamp: the first received is kept
            self.t_ns.insert(j, ti)
            self.t_s.insert(j, (ti - self.t0) * 1e-9)
            row = None if joint is None else (tuple(float(part[f][i, k]) for f in self.buf.fields), self.no_flags)
            self.rows.insert(j, row)
            keep.append(i)
        if joint is None and keep:
            self.pending.append(part if len(keep) == len(t) else
                                {key: (v[keep] if isinstance(v, np.ndarray) else v) for key, v in part.items()})

    def convert(self, prod: TickProducer) -> None:
        """The pending messages' column values, by ``signals_for`` (one call for all of them)."""
        if not self.pending:
            return
        parts, self.pending = self.pending, []
        part = parts[0] if len(parts) == 1 else {
            k: (np.concatenate([p[k] for p in parts]) if isinstance(v, np.ndarray) else v) for k, v in parts[0].items()}
        t = part["t_ns"]
        sig = signals_for(prod.scan.topics[self.topic].src, part, (t - self.t0) * 1e-9, prod.robot, prod.tmap,
                          prod.plan.facts[self.topic])
        vals = list(zip(*[s.values.tolist() for s in sig]))
        flags = [None if s.extra_invalid is None else s.extra_invalid.tolist() for s in sig]
        for i, ti in enumerate(t.tolist()):
            j = bisect_left(self.t_ns, ti)
            if j < len(self.t_ns) and self.t_ns[j] == ti and self.rows[j] is None:
                self.rows[j] = (vals[i], tuple(None if f is None else f[i] for f in flags))

    def settled(self, g: float, frontier_ns: float, need_gap_s: float) -> bool:
        """``Producer._settled`` for the tick ``g``."""
        if frontier_ns == math.inf:
            return True
        j = bisect_right(self.t_s, g + _EPS)
        if j < len(self.t_s) and self.t_ns[j] <= frontier_ns:
            return True
        return (frontier_ns - self.t0) * 1e-9 > g + need_gap_s + 1e-6

    def trim(self, g_next: float) -> None:
        """Drop what no later tick can use: keep from the last sample at or before ``g_next``."""
        keep = bisect_right(self.t_s, g_next + _EPS) - 1
        if keep > 0:
            del self.t_ns[:keep], self.t_s[:keep], self.rows[:keep]

    def sample(self, g: float, data: dict, valid: dict) -> float | None:
        """This source's columns at tick ``g`` into ``data``/``valid``; returns the stamp of the label
        sample held (``terrain`` source only, inf when none)."""
        n = len(self.t_s)
        idx = bisect_right(self.t_s, g + _EPS)
        lo = self.rows[idx - 1] if idx else None
        hi = self.rows[idx] if idx < n else None
        t_lo = self.t_s[idx - 1] if lo is not None else None
        t_hi = self.t_s[idx] if hi is not None else None
        label_t = None
        for c, col in enumerate(self.cols):
            v_lo = lo[0][c] if lo is not None else math.nan
            v_hi = hi[0][c] if hi is not None else math.nan
            out, ok = at_tick(g, t_lo, v_lo, t_hi, v_hi, self.methods[c], self.gaps[c])
            if ok and lo[1][c] is not None and lo[1][c] > 0.5:
                ok = False                        # low confidence (the flag held, as assemble does)
            if col == "terrain":
                label_t = math.inf if t_lo is None else t_lo
                s = self.buf.signals[c]
                if s.period_s is not None and t_lo is not None:
                    pair = Signal(col, np.array(self.t_s[idx - 1:idx + 1]), np.zeros(0), s.method, s.max_gap_s,
                                  period_s=s.period_s)
                    stale = label_stream_stale(pair, np.array([g]))[0]
                    out = math.nan if stale else out
            elif col.startswith("gt_state"):
                out = _STATE_NAMES[int(out)] if math.isfinite(out) and 0 <= int(out) < 4 else "unknown"
            data[col] = out
            valid[col] = ok
        return label_t


class TickProducer:
    """:class:`~terrainml.io.ingest.logs.Producer` (same plan, input and settling) emitting one sample
    dict per tick into ``out`` (module docstring), from tick ``first_tick`` on. The grid ends where
    the plan ends it, or, for a live stream whose plan is unbounded, at :meth:`finish`.

    Parameters
    ----------
    p : the plan (its buffers are filled by :meth:`on_part`).
    tmap, robot : the topic map and robot the plan was made for.
    rate_hz : base rate, Hz.
    out : list the sample dicts are appended to.
    first_tick : index of the first tick emitted (a new timeline continues the grid there).
    """

    def __init__(self, p: Plan, tmap: TopicMap, robot: RobotSpec, rate_hz: float, out: list[dict],
                 first_tick: int = 0):
        self.plan, self.tmap, self.robot, self.rate_hz, self.out = p, tmap, robot, float(rate_hz), out
        self.scan, self.t0 = p.scan, p.t0_ns
        self._next_tick = int(first_tick)
        self.topic_max: dict[str, int] = {}
        self.all_max: int | None = None
        self.hole_s = -math.inf      # last tick served with no sensor group valid
        self.rings = [_Ring(b, self.t0) for b in p.buffers]
        self.by_topic: dict[str, list[_Ring]] = {}
        for r in self.rings:
            self.by_topic.setdefault(r.topic, []).append(r)
        spec = column_map(robot.n_wheels)
        present = list(dict.fromkeys(c for r in self.rings for c in r.cols))
        self.zeros, self.absent = filled_columns(["t_s"] + present, robot, spec)
        self.members = [(valid_column(g).name, m) for g, m in
                        validity_members(present + self.zeros + self.absent, spec).items()]
        names = ["t_s"] + present + self.zeros + self.absent + [v for v, _ in self.members]
        self.order = [c for c in spec if c in names] + [c for c in names if c not in spec]

    @property
    def next_tick(self) -> int:
        """Index of the next tick to emit (ticks before it have been emitted)."""
        return self._next_tick

    @property
    def columns_by_topic(self) -> dict[str, list[str]]:
        """The run-table columns each mapped topic feeds."""
        cols: dict[str, list[str]] = {}
        for r in self.rings:
            topic_cols = cols.setdefault(r.topic, [])
            topic_cols += [c for c in r.cols if c not in topic_cols]
        return cols

    def finish(self) -> None:
        """End the grid at the latest stamp of a mapped source (as ingest ends it at the log's last
        message; never before the next tick) and emit every tick up to it."""
        ends = [m for topic, m in self.topic_max.items() if topic in self.by_topic]
        t_end_s = (max(ends) - self.t0) * 1e-9 if ends else (self._next_tick - 1) / self.rate_hz
        self.plan.n_ticks = max(int(math.floor(t_end_s * self.rate_hz + 1e-6)) + 1, self._next_tick)
        self.drain(final=True)

    def on_part(self, topic: str, part: dict) -> None:
        t = part["t_ns"]
        if len(t) == 0 or topic not in self.scan.topics:
            return
        hi = int(t[0]) if len(t) == 1 else int(t.max())
        self.all_max = hi if self.all_max is None else max(self.all_max, hi)
        self.topic_max[topic] = max(self.topic_max.get(topic, hi), hi)
        for r in self.by_topic.get(topic, ()):
            r.add(part)

    def _frontiers_ns(self) -> dict[str, float]:
        """``Producer._frontier_ns`` of every topic, live (never exhausted)."""
        every = self.all_max - self.scan.lateness_all_ns
        return {topic: max(self.topic_max[topic] - ts.lateness_ns, every) if topic in self.topic_max else every
                for topic, ts in self.scan.topics.items()}

    def drain(self, final: bool, settle: bool = True) -> int:
        """Emit every settled tick (``final``: every tick up to ``plan.n_ticks``); returns how many.

        ``settle=False`` (live, every source silent): every tick up to the latest stamp now,
        without waiting for the messages that would settle it -- a source without a message after
        a tick has it as at the end of a log -- and the grid goes on.
        """
        if self.all_max is None and not final:
            return 0
        n_ticks = self.plan.n_ticks
        if final:
            hi = n_ticks
            fronts = None
        else:
            hi = min(int(math.floor((self.all_max - self.t0) * 1e-9 * self.rate_hz + 1e-6)) + 1, n_ticks)
            if hi <= self._next_tick:
                return 0
            fronts = self._frontiers_ns() if settle else None
        a = self._next_tick
        while self._next_tick < hi:
            g = self._next_tick / self.rate_hz
            if fronts is not None and not all(r.settled(g, fronts[r.topic], r.buf.need_gap_s) for r in self.rings):
                break
            if self._next_tick == a:
                for r in self.rings:
                    r.convert(self)
            self.out.append(self._tick(g))
            self._next_tick += 1
        if final and self._next_tick >= n_ticks:
            for r in self.rings:
                r.t_ns, r.t_s, r.rows, r.pending = [], [], [], []
        elif self._next_tick > a:
            g_next = self._next_tick / self.rate_hz
            for r in self.rings:
                r.trim(g_next)
        return self._next_tick - a

    def _tick(self, g: float) -> dict:
        """One row of the run table (``assemble``'s column rules)."""
        data: dict = {"t_s": g}
        valid: dict[str, bool] = {}
        label_t = None
        for r in self.rings:
            lt = r.sample(g, data, valid)
            if lt is not None:
                label_t = lt
        for c in self.zeros:
            data[c], valid[c] = 0.0, True
        for c in self.absent:
            data[c], valid[c] = math.nan, False
        alive = False
        for name, members in self.members:
            ok = bool(members) and all(valid[c] for c in members)
            data[name] = ok
            alive |= ok
        if not alive:
            self.hole_s = g                       # the last hole tick so far (assemble's last_dead)
        if "terrain" in data:
            t = data["terrain"]
            if label_t is not None and self.hole_s > label_t + _EPS:
                t = math.nan                      # a label is never held across a hole
            data["terrain"] = int(t) if math.isfinite(t) else -1
        return {c: data[c] for c in self.order}
