"""Live messages -> base-rate samples, by the ingest engine's own rules (design §5).

A live transport (the ROS 2 source) hands decoded messages -- the parts of :mod:`terrainml.io.cdr`,
made by :func:`terrainml.io.cdr.from_object`, the decoder ingest uses for deserialised messages --
to :class:`LiveAligner`, which turns them into base-rate samples with the engine of MCAP ingest
(:mod:`terrainml.io.ingest.logs`): its scan and plan on a warm-up window, then its produce step one
tick at a time, :class:`~terrainml.io.ingest.ticks.TickProducer` (the chunk producer's settling
test and rules in plain floats: each message converted once, each tick interpolated from the two
messages that bracket it, no DataFrame: about 0.5 ms of CPU a tick on the reference robot's inputs,
where the chunk producer took 6-8 ms). Stamps, units, frames, IMU mount, T265 lever arm,
resampling, gap rule and validity are therefore those of ``terrainml ingest`` on a recording of the
same messages, and so are the samples: a tick is emitted as soon as every source is *settled* past
it (its next message is known, or an unseen one could no longer bracket the tick within the gap
rule). No wait is added for a topic that publishes in order: the message after the tick settles it;
``reorder_s`` only bounds how long a silent topic is waited for.

What a whole log tells ingest and a live stream cannot know, and how the aligner decides it
(departures from ingest, exact for publishers at steady rates that are in order):

* **time origin**: the earliest stamp of the warm-up (the first ``warmup_s`` of stamps, 0.5 s by
  default, and at least one message of every required topic or ``warmup_wait_s`` of wall time);
* **gap thresholds, IMU orientation, first T265 pose, joint names**: taken from the warm-up
  (ingest: from the whole log); a topic that starts publishing after the warm-up is not used (a
  warning names it);
* **lateness**: ``reorder_s`` (default 0.05 s) is how far one topic may lag behind the others in
  delivery before its ticks are decided without it. A topic that stops (a stale publisher) thus
  becomes invalid ``reorder_s`` plus its gap threshold after its last message, and the served
  messages say so within the predictor's sensor timeout. A message stamped before a tick already
  emitted is *late*: counted per topic and, as on the UDP source, not served retroactively (it
  still brackets the ticks after it);
* **end**: :meth:`LiveAligner.finish` ends the grid at the last stamp, as ingest ends it at the
  log's last message;
* **total silence**: once every topic has been silent for :data:`FLUSH_AFTER_S` of wall time, the
  source calls :meth:`LiveAligner.flush`: the ticks up to the latest stamp are decided as at the
  end of a log (a topic without a message after a tick has it as there), and the grid goes on.

Pauses and clock jumps: a message stamped within ``max_gap_s`` (the clock policy's G, 1 s) of its
own topic's last stamp, or of the stream's latest stamp, is on the timeline -- so one topic's
backlog delivered after another's is never taken for a jump, and a topic that paused (a driver
restart, a USB IMU that dropped out, for any length of time) rejoins the timeline where the other
topics are with its first message, logged (``topic /imu publishes again after 10.0 s``). Any
other message is off the timeline and held. ``reanchor_after`` (K, 5) consistent held messages
from two topics or more start a new timeline there: the old one is finished and the grid
continues at the new stamps (same time origin), so the predictor sees the jump in ``t_s`` and applies its clock policy
(:mod:`terrainml.stream.tick.clock`). Held messages are dropped and counted when their topic comes back
on its timeline (one publisher with a wild clock), and so are the old timeline's stragglers.

Return after total silence: when every topic has been silent on the wall clock for at least
:data:`RESUME_WALL_S` and half as long as a new message's stamp is ahead of the stream's latest,
that message starts the new timeline at once (no K candidates: topics delivered unevenly after a
stall would otherwise be dropped as inconsistent), and the log says so instead of "clock jump";
the predictor re-anchors the same way (its estimator and windows restart on the fresh data). A
topic new to a timeline is on it from the timeline's first stamp minus G on, so one that lags
the others after the return joins it late instead of being held.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from terrainml.io.ingest.logs import Plan, Scan, plan
from terrainml.io.ingest.ingest_report import IngestReport
from terrainml.io.ingest.signals import validity_members
from terrainml.io.ingest.ticks import TickProducer
from terrainml.io.topicmap import TopicMap
from terrainml.robot import RobotSpec
from terrainml.schema import DEFAULT_RATE_HZ, VALID_GROUPS, column_map
from terrainml.stream.tick.clock import MAX_GAP_S, REANCHOR_AFTER

log = logging.getLogger("terrainml.stream")

WARMUP_S = 0.5
#: every topic silent this long on the wall clock (s) before stamps far ahead are a return, not a jump
RESUME_WALL_S = 0.5
WARMUP_WAIT_S = 2.0
REORDER_S = 0.05
#: every topic silent this long on the wall clock (s): the ticks up to the latest stamp are decided.
#: Later than ``/diagnostics`` says "no input" (1 s), so those stale ticks are published while the
#: diagnostics already say ERROR, never beside a status of the time before the silence
FLUSH_AFTER_S = 1.5
#: grid length of a live timeline until it ends
_UNBOUNDED = 2**62


@dataclass
class AlignCounters:
    """Messages per topic: received, used late (after their tick was served), dropped off-timeline."""

    received: dict[str, int] = field(default_factory=dict)
    late: dict[str, int] = field(default_factory=dict)
    off_timeline: dict[str, int] = field(default_factory=dict)
    ignored: dict[str, int] = field(default_factory=dict)     # topics first seen after the warm-up
    timelines: int = 0

    def bump(self, which: dict[str, int], topic: str, n: int = 1) -> int:
        which[topic] = which.get(topic, 0) + n
        return which[topic]


class _WarmupLog:
    """The warm-up's messages as the engine's log interface (``read`` replays them)."""

    kept = True

    def __init__(self, name: str, parts: list[tuple[str, dict]]):
        self.path = Path(name)
        self.parts = parts

    def read(self, on_part, topics: set[str] | None = None) -> None:
        for topic, p in self.parts:
            if topics is None or topic in topics:
                on_part(topic, p)


class LiveAligner:
    """Base-rate samples from live messages (rules in the module docstring).

    Parameters
    ----------
    tmap : the topic map (which topics feed which columns).
    robot : RobotSpec (wheel count, IMU mount, camera lever arm).
    rate_hz : base rate, Hz.
    name : what warnings call the stream (e.g. ``ros2://0``).
    required : topics the warm-up waits for (default: the map's non-optional topics).
    warmup_s, warmup_wait_s, reorder_s : s (module docstring).
    max_gap_s, reanchor_after : the clock policy's G (s) and K.
    """

    def __init__(self, tmap: TopicMap, robot: RobotSpec, rate_hz: float = DEFAULT_RATE_HZ, *,
                 name: str = "live", required: list[str] | None = None, warmup_s: float = WARMUP_S,
                 warmup_wait_s: float = WARMUP_WAIT_S, reorder_s: float = REORDER_S,
                 max_gap_s: float = MAX_GAP_S, reanchor_after: int = REANCHOR_AFTER):
        self.tmap, self.robot, self.rate_hz, self.name = tmap, robot, float(rate_hz), name
        self.required = set(required if required is not None else
                            [s.topic for s in tmap.sources if not s.options.get("optional")])
        self.warmup_ns, self.warmup_wait_s = int(warmup_s * 1e9), float(warmup_wait_s)
        self.reorder_ns, self.max_gap_ns = int(reorder_s * 1e9), int(max_gap_s * 1e9)
        self.reanchor_after = int(reanchor_after)
        self.counters = AlignCounters()
        #: sensor groups a topic of the map feeds (known when the warm-up ends)
        self.mapped_groups: list[str] | None = None
        self.watch: Any = None   # an InputWatch told the mapped groups (the source sets it)
        self.report = IngestReport(source=name, format="ros2", rate_hz=self.rate_hz)
        self._early: list[tuple[str, dict]] = []
        self._first_wall: float | None = None
        self._plan: Plan | None = None
        self._prod: TickProducer | None = None
        self._out: list[dict] = []
        self._cand: dict[str, list[tuple[str, dict]]] = {}
        self._latest_ns: int | None = None
        self._last_wall = time.monotonic()   # when the latest stamp arrived (total silence vs. clock jump)
        self._start_ns = -_UNBOUNDED         # first stamp of the current timeline
        self._last: dict[str, int] = {}      # per topic: last stamp on the current timeline
        self._old: dict[str, int] = {}       # ... on the previous one (its stragglers are dropped)

    # ------------------------------------------------------------------ public
    @property
    def t0_ns(self) -> int | None:
        """Time origin (ns): ``t_s`` of a sample is seconds after it; None before the warm-up ends."""
        return None if self._plan is None else self._plan.t0_ns

    @property
    def started(self) -> bool:
        return self._prod is not None

    def add(self, topic: str, part: dict) -> None:
        """Take one decoded message (a one-row part of :mod:`terrainml.io.cdr`)."""
        self.counters.bump(self.counters.received, topic)
        if self._prod is None:
            self._warmup(topic, part)
            return
        if topic not in self._prod.scan.topics:
            if self.counters.bump(self.counters.ignored, topic) == 1:
                log.warning("%s: topic %s started publishing after the warm-up: not used (restart to use it)",
                            self.name, topic)
            return
        self._timeline(topic, part)

    def lag_s(self, topic: str) -> float | None:
        """How far ``topic``'s latest stamp is behind the stream's latest, s (None: not on the timeline)."""
        last = self._last.get(topic)
        return None if last is None or self._latest_ns is None else (self._latest_ns - last) * 1e-9

    def poll(self, wait_all: bool = False) -> list[dict]:
        """Samples of the ticks settled so far (in order); starts the stream after the warm-up.

        ``wait_all``: decide no tick without a topic that lags the others (the process just
        lagged, :meth:`terrainml.stream.tick.inputs.InputWatch.in_grace`: its messages may still be
        on their way), instead of waiting only ``reorder_s`` of stamps for it.
        """
        if self._prod is None:
            if not self._warmup_done():
                return []
            self._start()
        elif wait_all:
            with self._prod.scan.cross_lateness(_UNBOUNDED):
                self._prod.drain(final=False)
        else:
            self._prod.drain(final=False)
        out, self._out[:] = self._out[:], []
        return out

    def flush(self) -> list[dict]:
        """Every topic silent (on the wall clock, :data:`FLUSH_AFTER_S`): the ticks up to the latest
        stamp now, without the messages that would settle them (as at the end of a stream); the
        timeline goes on. Without it those ticks would wait for the return, however late."""
        if self._prod is None:
            return []
        self._prod.drain(final=False, settle=False)
        out, self._out[:] = self._out[:], []
        return out

    def finish(self) -> list[dict]:
        """End of stream: the remaining ticks up to the last stamp."""
        if self._prod is None and self._early:
            self._start()
        if self._prod is not None:
            self._end_timeline()
        out, self._out[:] = self._out[:], []
        return out

    # ------------------------------------------------------------------ warm-up
    def _warmup(self, topic: str, part: dict) -> None:
        if self._first_wall is None:
            self._first_wall = time.monotonic()
        self._early.append((topic, part))

    def _warmup_done(self) -> bool:
        if not self._early:
            return False
        stamps = [int(p["t_ns"][0]) for _, p in self._early]
        seen = {t for t, _ in self._early}
        span_ok = max(stamps) - min(stamps) >= self.warmup_ns
        waited = time.monotonic() - (self._first_wall or time.monotonic()) >= self.warmup_wait_s
        return span_ok and (self.required <= seen or waited)

    def _start(self) -> None:
        """Scan and plan the warm-up with the ingest engine, then replay it into a producer."""
        rep = self.report
        scan = Scan(self.tmap, self.robot, self.rate_hz, None)
        for topic, p in self._early:
            scan.on_part(topic, p)
        scan.drain()
        for topic, ts in scan.topics.items():
            rep.topics[topic] = {"type": ts.src.type, "mapped": True, "read": ts.rows, "decoded": ts.rows,
                                 "corrupt": 0, "skipped": 0, "out_of_order": 0, "duplicates": 0,
                                 "non_finite": 0}
        for src in self.tmap.sources:
            if src.topic not in scan.topics and not src.options.get("optional"):
                log.warning("%s: mapped topic %s (%s) had no message in the warm-up: not used",
                            self.name, src.topic, src.type or src.kind)
        p = plan(scan, _WarmupLog(self.name, self._early), self.tmap, self.robot, self.rate_hz, rep)
        if p is None:
            raise ValueError("; ".join(rep.errors) or f"{self.name}: no usable message")
        for w in rep.warnings:
            log.warning("%s", w)
        scan.allow_cross_lateness(self.reorder_ns)
        self._plan = p.emptied(_UNBOUNDED)
        self._prod = TickProducer(self._plan, self.tmap, self.robot, self.rate_hz, self._out)
        topic_cols = self._prod.columns_by_topic
        present = sorted({c for cols in topic_cols.values() for c in cols})
        self.mapped_groups = [g for g, cols in validity_members(present, column_map(self.robot.n_wheels)).items()
                              if cols and g in VALID_GROUPS]
        if self.watch is not None:
            self.watch.mapped_groups = list(self.mapped_groups)
            spec = column_map(self.robot.n_wheels)
            for topic, cols in topic_cols.items():
                self.watch.topic_groups.setdefault(topic, set()).update(
                    spec[c].group for c in cols if c in spec and spec[c].group in VALID_GROUPS)
        self.counters.timelines = 1
        self._start_ns = self._plan.t0_ns
        early, self._early = self._early, []
        for topic, part in early:
            self._feed(topic, part)
        self._prod.drain(final=False)

    # ------------------------------------------------------------------ timeline
    def _feed(self, topic: str, part: dict) -> None:
        t = int(part["t_ns"][0])
        if (t - self._plan.t0_ns) * 1e-9 < (self._prod.next_tick - 1) / self.rate_hz - 1e-9:
            n = self.counters.bump(self.counters.late, topic)
            if n <= 3 or n % 1000 == 0:
                log.warning("%s: topic %s: message stamped %.3f s arrived after its tick was served "
                            "(%d late so far)", self.name, topic, (t - self._plan.t0_ns) * 1e-9, n)
        if self._latest_ns is None or t >= self._latest_ns:
            self._latest_ns, self._last_wall = t, time.monotonic()
        self._last[topic] = max(self._last.get(topic, t), t)
        self._prod.on_part(topic, part)

    def _drop(self, cand: list[tuple[str, dict]], why: str) -> None:
        for c_topic, _ in cand:
            self.counters.bump(self.counters.off_timeline, c_topic)
        if cand:
            log.warning("%s: %d message(s) off the timeline dropped (%s)", self.name, len(cand), why)

    def _timeline(self, topic: str, part: dict) -> None:
        """On the timeline: fed; off it: held as a candidate new timeline (clock policy).

        A message is on the timeline when it is within G of its own topic's last stamp (a topic
        new to the timeline: of the latest stamp), so one topic's backlog delivered after another's
        is never a jump. A candidate timeline is confirmed by K consistent messages from two topics
        or more (one publisher with a wild clock is dropped, counted), and ended by a message of
        one of its topics back on the old timeline."""
        t = int(part["t_ns"][0])
        g = self.max_gap_ns
        last = self._last.get(topic)
        ref = last if last is not None else self._latest_ns
        latest = self._latest_ns
        # a topic new to this timeline that lags the others (a backlog after a new timeline)
        joins = last is None and latest is not None and self._start_ns - g <= t <= latest + g
        if ref is None or abs(t - ref) <= g or (latest is not None and abs(t - latest) <= g) or joins:
            # within G of its own last stamp, or of the stream's latest: a topic that paused
            # while the others went on rejoins the timeline where they are
            if last is not None and t - last > g:
                log.warning("%s: topic %s publishes again after %.1f s without messages (stamps %.3f -> %.3f s)",
                            self.name, topic, (t - last) * 1e-9, (last - self._plan.t0_ns) * 1e-9,
                            (t - self._plan.t0_ns) * 1e-9)
            self._drop(self._cand.pop(topic, []), f"topic {topic} back on its timeline")
            self._feed(topic, part)
            return
        if last is None and topic in self._old and abs(t - self._old[topic]) <= g:
            self.counters.bump(self.counters.late, topic)    # a straggler of the previous timeline
            return
        if latest is not None and t > latest and not self._cand:
            wall_s = time.monotonic() - self._last_wall
            if wall_s >= max(RESUME_WALL_S, 0.5 * (t - latest) * 1e-9):
                # every topic was silent on the wall clock about as long as the stamps moved: a
                # return after total silence, not a wild clock; the new timeline starts here
                self._cand = {topic: [(topic, part)]}
                self._new_timeline()
                return
        held = [p for ps in self._cand.values() for _, p in ps]
        if held and abs(t - max(int(p["t_ns"][0]) for p in held)) > g:
            self._drop([c for ps in self._cand.values() for c in ps], "inconsistent stamps")
            self._cand = {}
        self._cand.setdefault(topic, []).append((topic, part))
        n = sum(len(ps) for ps in self._cand.values())
        if n >= self.reanchor_after and len(self._cand) >= min(2, max(len(self._last), 1)):
            self._new_timeline()

    def _end_timeline(self) -> None:
        self._prod.finish()

    def _new_timeline(self) -> None:
        """K consistent off-timeline messages: finish the old timeline, start one at their stamps."""
        cand = sorted((c for ps in self._cand.values() for c in ps), key=lambda c: int(c[1]["t_ns"][0]))
        self._cand = {}
        self._end_timeline()
        first = int(cand[0][1]["t_ns"][0])
        self._start_ns = first
        step_s = (first - self._latest_ns) * 1e-9
        wall_s = time.monotonic() - self._last_wall
        if step_s > 0 and wall_s >= 0.5 * step_s:   # (a loaded publisher catches up: not exactly as far)
            log.warning("%s: every topic publishes again after %.1f s of silence (stamps moved %.3f s, about as "
                        "far as the wall clock); a new timeline starts there", self.name, wall_s, step_s)
        else:
            log.warning("%s: clock jump: stamps moved %.3f s; a new timeline starts there", self.name, step_s)
        self._plan = self._plan.emptied(_UNBOUNDED)
        first_tick = int(math.ceil((first - self._plan.t0_ns) * 1e-9 * self.rate_hz - 1e-6))
        self._prod = TickProducer(self._plan, self.tmap, self.robot, self.rate_hz, self._out, first_tick)
        self._latest_ns = None
        self._old, self._last = self._last, {}
        self.counters.timelines += 1
        for topic, part in cand:
            self._feed(topic, part)

    def stats(self) -> dict[str, Any]:
        c = self.counters
        return {"received": dict(c.received), "late": dict(c.late), "off_timeline": dict(c.off_timeline),
                "ignored": dict(c.ignored), "timelines": c.timelines}

