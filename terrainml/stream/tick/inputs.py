"""Per-topic freshness of a live source on the process's monotonic clock (ROS 2 faults, docs/ros2.md).

:class:`InputWatch` is shared by a live source, which reports every message it takes, and a sink,
whose ``/diagnostics`` timer reads it once a second (:mod:`terrainml.stream.transports.ros2.sink`). It
judges each input topic on the wall clock, independently of the stamps the aligner and the
health monitor judge ticks by:

* **rate**: messages received per second over the last :data:`RATE_WINDOW_S` (2 s);
* **timeout**: a topic is silent when nothing arrived for longer than its own timeout,
  ``max(MIN_TIMEOUT_S, TIMEOUT_PERIODS / rate)`` with the rate it had while it published (a
  100 Hz IMU: 0.5 s; a 2 Hz topic: 5 s);
* **loop lag**: the source reports each pass of its loop (:meth:`InputWatch.loop`). A pass that
  comes later than its wait allows (the process did not run: another process held the CPU, or
  the predictor worked through a backlog) is a lag; the silence of every topic that was on time
  when the lag began (within :data:`ON_TIME_SHARE` of its timeout) then restarts from the pass after it (a topic
  overdue then was going silent before the lag, and counts on from its last message), and for
  a grace of twice the lag (at least :data:`MIN_GRACE_S`, at most :data:`MAX_GRACE_S`) the
  source waits for every topic before a tick is decided without one
  (:meth:`InputWatch.in_grace`). The total silence (:meth:`InputWatch.idle_s`) likewise restarts
  after a lag that began while input flowed (a message within :data:`NO_INPUT_S`); input already
  silent for longer when the lag began counts on from its last message. Messages that waited in a
  reader's queue, or that the process could not take, are thus never a silence, and the work a
  silence brings (the aligner's flush and its last ticks) never hides it;
* **invalid values**: NaN or infinite numbers, counted per topic and field (``velocity[left]``,
  ``gyro``); a message with them is not a silence.

A topic is silent alone when its age exceeds its timeout, counted from the moment the *least
overdue* topic should have had its next message (each topic's age less its own period): when
delivery stalls as a whole (the publisher starved, or this process's receive path), every topic
ages together, and none is singled out, whatever the phase each stalled at; a slow topic between
two of its messages is not overdue and delays nothing. Once every topic has been silent for
:data:`NO_INPUT_S`, each is (total silence).

A topic's silence is logged once when it exceeds the timeout, and again when the topic is back
("fresh again after N s"); :meth:`InputWatch.idle_s` is how long every topic has been silent.
The clock is injectable (tests drive it by hand).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

log = logging.getLogger("terrainml.stream")

RATE_WINDOW_S = 2.0
MIN_TIMEOUT_S = 0.5
TIMEOUT_PERIODS = 5.0
#: a loop pass later than its wait by more than this is a lag (the process did not run)
LAG_S = 0.05
MIN_GRACE_S = 0.2
MAX_GRACE_S = 2.0
#: a topic whose age is within this share of its timeout when a loop lag begins is on time: the
#: lag restarts its silence count (module docstring)
ON_TIME_SHARE = 0.5
#: a group whose topic brought invalid values this recently is "invalid values", not "silent", s
INVALID_RECENT_S = 0.5
#: arrivals the publishing rate is measured over
RECENT = 11
#: every input silent for longer than this: ``/diagnostics`` says ERROR "no input for N s"
NO_INPUT_S = 1.0


@dataclass
class TopicWatch:
    """What is known of one input topic (times on the watch's monotonic clock, s)."""

    topic: str
    type: str
    optional: bool = False
    received: int = 0
    last_rx_s: float | None = None
    rx: deque = field(default_factory=deque)
    recent: deque = field(default_factory=lambda: deque(maxlen=RECENT))
    rate_hz_seen: float = 0.0          # the rate it had while it published (sets its timeout)
    invalid: dict[str, int] = field(default_factory=dict)
    silent: bool = False
    silent_since_s: float | None = None
    episodes: int = 0
    last_invalid_s: float | None = None
    resume_s: float = -math.inf        # the end of the last loop lag that found it on time

    @property
    def invalid_values(self) -> int:
        return sum(self.invalid.values())

    def period_s(self) -> float:
        """Its expected time between messages (s), from the rate it had while it published."""
        return 1.0 / self.rate_hz_seen if self.rate_hz_seen > 0 else 0.0

    def timeout_s(self) -> float:
        r = self.rate_hz_seen
        return max(MIN_TIMEOUT_S, TIMEOUT_PERIODS / r) if r > 0 else MIN_TIMEOUT_S


def _stamp_s(part: dict | None, now: float) -> float:
    """A message's stamp (s) from its decoded part; the arrival time when it has none."""
    t = None if part is None else part.get("t_ns")
    return float(t[0]) * 1e-9 if t is not None and len(t) else now


class InputWatch:
    """Freshness, rates and invalid values of a live source's topics (module docstring).

    Parameters
    ----------
    clock : callable returning seconds (default ``time.monotonic``).
    """

    def __init__(self, clock: Callable[[], float] = time.monotonic):
        self.clock = clock
        self.topics: dict[str, TopicWatch] = {}
        self.mapped_groups: list[str] | None = None   # the sensor groups the source's map feeds
        self.topic_groups: dict[str, set[str]] = {}   # topic -> the sensor groups it feeds
        self.started_s = clock()
        self._resume_s = -math.inf     # the first loop pass after the last lag
        self._grace_until_s = -math.inf
        self._last_loop_s: float | None = None
        self.lags = 0
        self.max_lag_s = 0.0
        self.lock = threading.RLock()   # the diagnostics timer reads while the source writes

    # ------------------------------------------------------------------ the source's side
    def add_topic(self, topic: str, type_name: str, optional: bool = False) -> None:
        self.topics[topic] = TopicWatch(topic, type_name, optional)

    def loop(self, wait_s: float, now: float | None = None) -> float:
        """One pass of the source's loop, which waited at most ``wait_s``; returns its lag (s)."""
        now = self.clock() if now is None else now
        last, self._last_loop_s = self._last_loop_s, now
        lag = 0.0 if last is None else now - last - wait_s
        if lag > LAG_S:
            with self.lock:
                self.lags += 1
                self.max_lag_s = max(self.max_lag_s, lag)
                # the lag may hide messages of input that flowed when it began: the total silence
                # restarts after it; input already silent beyond NO_INPUT_S when it began (the
                # diagnostics said so) counts on from its last message, so the work the silence
                # itself brings (the aligner's flush, its late ticks) never turns it back to OK
                if self._unheard_s(last) <= NO_INPUT_S:
                    self._resume_s = now
                # the lag hides what the process could not take: a topic on time when it began
                # (within half its timeout) counts its age from now; one overdue then was going
                # silent before the lag, and goes on counting from its last message (lags every
                # half second on a busy machine would otherwise never let a paused topic be
                # silent, and made a silent one look fresh after each)
                for tw in self.topics.values():   # (a lag needs a pass before: last is set)
                    if self._topic_age(tw, last) <= ON_TIME_SHARE * tw.timeout_s():
                        tw.resume_s = now
                self._grace_until_s = now + min(max(2.0 * lag, MIN_GRACE_S), MAX_GRACE_S)
            return lag
        return 0.0

    def _unheard_s(self, now: float) -> float:
        """Wall seconds at ``now`` since any topic's last message (since the start: none yet),
        loop lags included."""
        rx = [tw.last_rx_s for tw in self.topics.values() if tw.last_rx_s is not None]
        return now - max(rx + [self.started_s])

    def in_grace(self, now: float | None = None) -> bool:
        """True shortly after a loop lag: a tick then waits for every topic (module docstring)."""
        return (self.clock() if now is None else now) < self._grace_until_s

    def on_message(self, topic: str, part: dict | None = None, now: float | None = None,
                   empty: frozenset[str] = frozenset()) -> None:
        """A message of ``topic`` was taken (``part``: its decoded fields, for invalid values;
        ``empty``: fields the message left empty, which the decoder fills with NaN)."""
        tw = self.topics.get(topic)
        if tw is None:
            return
        now = self.clock() if now is None else now
        with self.lock:
            tw.received += 1
            tw.last_rx_s = now
            tw.rx.append(now)
            while tw.rx and tw.rx[0] < now - RATE_WINDOW_S:
                tw.rx.popleft()
            # the rate it publishes at, from its own stamps (arrivals come in bursts when delivery
            # stalls) over its last messages, however slow; a pause does not lower it
            stamp = _stamp_s(part, now)
            if tw.recent and 0 <= stamp - tw.recent[-1] <= 2.0 * tw.timeout_s():
                tw.recent.append(stamp)
            elif not tw.recent or stamp > tw.recent[-1]:
                tw.recent.clear()
                tw.recent.append(stamp)
            if len(tw.recent) >= 3 and tw.recent[-1] > tw.recent[0]:
                tw.rate_hz_seen = (len(tw.recent) - 1) / (tw.recent[-1] - tw.recent[0])
            if tw.silent:
                self._fresh_again(tw, now)
            if part is not None:
                self._count_invalid(tw, part, empty)

    @staticmethod
    def _count_invalid(tw: TopicWatch, part: dict, empty: frozenset[str]) -> None:
        names = part.get("names")
        for key, v in part.items():
            if not isinstance(v, np.ndarray) or v.dtype.kind != "f" or key == "t_ns" or key in empty:
                continue
            bad = ~np.isfinite(v)
            if not bad.any():
                continue
            if names and v.ndim == 2 and v.shape[1] == len(names):
                for j in np.flatnonzero(bad.any(axis=0)):
                    k = f"{key}[{names[j]}]"
                    tw.invalid[k] = tw.invalid.get(k, 0) + 1
            else:
                tw.invalid[key] = tw.invalid.get(key, 0) + 1
            tw.last_invalid_s = tw.last_rx_s

    # ------------------------------------------------------------------ judgement
    def _rate(self, tw: TopicWatch, now: float) -> float:
        """Messages received per second over the last :data:`RATE_WINDOW_S` (or since the start)."""
        span = min(RATE_WINDOW_S, max(now - self.started_s, 1e-9))
        return sum(1 for t in tw.rx if t >= now - RATE_WINDOW_S) / span

    def rate_hz(self, topic: str, now: float | None = None) -> float:
        now = self.clock() if now is None else now
        return self._rate(self.topics[topic], now)

    def age_s(self, topic: str, now: float | None = None) -> float | None:
        """Wall seconds since the topic's last message (None: never), not counting a loop lag."""
        now = self.clock() if now is None else now
        tw = self.topics[topic]
        if tw.last_rx_s is None:
            return None
        return self._topic_age(tw, now)

    def _topic_age(self, tw: TopicWatch, now: float) -> float:
        """Seconds since the topic's last message (since the start: none yet), from the end of the
        last loop lag that found it on time."""
        return now - max(self.started_s if tw.last_rx_s is None else tw.last_rx_s, tw.resume_s)

    def update(self, now: float | None = None) -> list[tuple[str, float]]:
        """Judge every topic now: log the new silences; returns the silent ``(topic, age_s)``."""
        now = self.clock() if now is None else now
        out = []
        with self.lock:
            ages = {tw.topic: self._topic_age(tw, now) for tw in self.topics.values() if not tw.optional}
            # a topic is silent alone when it is late beyond its timeout *behind the freshest
            # topic*: a stall of delivery as a whole (the publisher's or this process's) ages every
            # topic together, whatever the phase each stalled at, and is no topic's silence;
            # total silence is every topic's once it passes NO_INPUT_S
            total = min(ages.values(), default=0.0) > NO_INPUT_S
            freshest = min((max(ages[t] - self.topics[t].period_s(), 0.0) for t in ages), default=0.0)
            for tw in self.topics.values():
                if tw.optional:
                    continue
                ref = self.started_s if tw.last_rx_s is None else tw.last_rx_s
                age = ages[tw.topic]
                behind = age if total else age - freshest
                if age > tw.timeout_s() and behind > tw.timeout_s():
                    out.append((tw.topic, now - ref))
                    if not tw.silent and tw.last_rx_s is not None:   # (never seen: the source warns)
                        tw.silent, tw.silent_since_s = True, ref
                        tw.episodes += 1
                        log.warning("topic %s silent: no message for %.1f s (timeout %.2f s at %.0f Hz)",
                                    tw.topic, now - ref, tw.timeout_s(), tw.rate_hz_seen)
        return out

    def _fresh_again(self, tw: TopicWatch, now: float) -> None:
        since = tw.silent_since_s if tw.silent_since_s is not None else now
        tw.silent, tw.silent_since_s = False, None
        log.warning("topic %s fresh again after %.1f s without messages", tw.topic, now - since)

    def group_invalid(self, group: str) -> bool:
        """Whether a topic feeding ``group`` brought invalid values (NaN, inf) in its last
        :data:`INVALID_RECENT_S` of messages: the group is invalid, not silent. (Judged against
        the topic's own last message, not the wall clock: a stall of delivery changes nothing.)"""
        for topic, groups in self.topic_groups.items():
            tw = self.topics.get(topic)
            if (group in groups and tw is not None and tw.last_invalid_s is not None
                    and tw.last_rx_s is not None and tw.last_rx_s - tw.last_invalid_s <= INVALID_RECENT_S):
                return True
        return False

    def idle_s(self, now: float | None = None) -> float:
        """Wall seconds since any topic's last message (since the start when none came yet)."""
        now = self.clock() if now is None else now
        return min(self._unheard_s(now), now - self._resume_s)

    def silent_text(self, now: float | None = None) -> str:
        """``/imu (3.2 s), /joint_states (3.1 s)``: the silent required topics and how long."""
        now = self.clock() if now is None else now
        parts = []
        for tw in self.topics.values():
            if tw.optional:
                continue
            ref = self.started_s if tw.last_rx_s is None else tw.last_rx_s
            parts.append(f"{tw.topic} ({now - ref:.1f} s{'' if tw.last_rx_s is not None else ', never seen'})")
        return ", ".join(parts)

    def statuses(self, now: float | None = None) -> list[dict[str, Any]]:
        """One status per topic for ``/diagnostics``: level (0 OK, 1 WARN), message and values."""
        now = self.clock() if now is None else now
        with self.lock:
            return self._statuses(now)

    def _statuses(self, now: float) -> list[dict[str, Any]]:
        silent = dict(self.update(now))
        out = []
        for tw in self.topics.values():
            age = self.age_s(tw.topic, now)
            if tw.topic in silent:
                level = 1
                text = (f"{tw.topic} silent for {silent[tw.topic]:.1f} s (timeout {tw.timeout_s():.2f} s)"
                        if tw.last_rx_s is not None else f"{tw.topic}: no message yet")
            elif tw.invalid_values:
                level, text = 0, f"{tw.topic}: {tw.invalid_values} message(s) with invalid values"
            else:
                level, text = 0, f"{tw.topic} ok"
            values = {"topic": tw.topic, "type": tw.type, "rate_hz": f"{self.rate_hz(tw.topic, now):.1f}",
                      "age_s": "nan" if age is None else f"{age:.3f}", "timeout_s": f"{tw.timeout_s():.2f}",
                      "received": str(tw.received), "invalid_values": str(tw.invalid_values)}
            values.update({f"invalid_{k}": str(n) for k, n in sorted(tw.invalid.items())})
            out.append({"level": level, "name": f"terrainml: input {tw.topic}", "message": text, "values": values})
        return out
