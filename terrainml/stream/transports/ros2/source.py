"""Source ``ros2://[DOMAIN]``: samples from a ROS 2 robot's own topics over DDS.

``terrainml predict --source ros2://0 [--topics MAP.yaml]`` joins DDS domain ``DOMAIN`` as a ROS 2
participant (Cyclone DDS, the ``rmw_cyclonedds_cpp`` wire format; no ROS installation needed) and
subscribes to every topic of the topic map -- the same YAML that MCAP ingest reads, the default
map without ``--topics`` -- with the map's message types (:mod:`terrainml.stream.transports.ros2.types`).
Each received message is decoded by ingest's decoder (:func:`terrainml.io.cdr.from_object`:
header stamp, or the DDS source timestamp for types without a header, as ingest takes the log
time) and aligned into base-rate samples by :class:`~terrainml.stream.transports.ros2.align.LiveAligner`,
the ingest engine run live: the samples, and so the served decisions, are those of ``terrainml
predict --source LOG`` on a recording of the same messages.

Options (URL query, e.g. ``ros2://0?qos=reliable&reorder_s=0.1``):

==============  =============  =====================================================================
key             default        meaning
==============  =============  =====================================================================
qos             sensor_data    ``sensor_data`` (best effort, keep last 100) or ``reliable`` (keep
                               last 1000); a topic map entry's own ``qos:`` key overrides it per topic
discovery_s     2.0            how long to look for publishers at start (type check, warnings)
warmup_s        0.5            stamps the aligner plans from (:mod:`.align`)
reorder_s       0.05           delivery lag one topic may have behind the others
==============  =============  =====================================================================

Faults (documented behaviour, tested in ``tests/stream/test_ros2_interop.py``):

* a publisher whose DDS type differs from the map's type: refused at start (:class:`SourceError`
  naming the topic, the publisher's type and the map's type), also found later: logged as an error;
* no publisher on a required topic: a warning naming it, repeated every 10 s while nothing
  arrives; serving waits (no sample is produced from nothing);
* a publisher that stops: its sensor group goes invalid after its gap threshold plus
  ``reorder_s`` and the predictor serves ``estimator_unhealthy`` after its sensor timeout;
* bursts: every message waiting is taken at once and the ticks they settle are served in order;
  a message stamped before a tick already served is counted late (as the UDP source's late samples);
* a clock jump: handled by the aligner and then the predictor's clock policy (:mod:`.align`).

When every topic has been silent for :data:`~.align.FLUSH_AFTER_S` (1.5 s) of wall time, the ticks
up to the latest stamp are served then (:meth:`LiveAligner.flush`), not when the topics return.
The stream ends after ``idle_timeout_s`` without a message (``predict --idle-timeout-s``) or on
SIGINT/SIGTERM; at the end the remaining ticks up to the last stamp are served. Each sample
carries ``stamp_origin_ns`` (int): its ROS time is ``stamp_origin_ns + t_s`` (what the ROS 2 sink
stamps its messages with).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Any, Callable, Iterator

from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsPublication
from cyclonedds.core import ReadCondition, SampleState, WaitSet
from cyclonedds.domain import DomainParticipant
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from terrainml.io import cdr
from terrainml.io.topicmap import BUILTIN_MAPS, Source, TopicMap, load_topic_map
from terrainml.robot import RobotSpec, load_robot
from terrainml.schema import DEFAULT_RATE_HZ
from terrainml.stream.tick.clock import MAX_GAP_S, REANCHOR_AFTER
from terrainml.stream.tick.inputs import InputWatch
from terrainml.stream.tick.sample import Sample, typed_samples
from terrainml.stream.transports.ros2.align import FLUSH_AFTER_S, REORDER_S, WARMUP_S, LiveAligner
from terrainml.stream.transports.ros2.names import (
    QOS_PROFILES, Ros2NameError, dds_topic_name, dds_type_name, parse_url, qos_for, ros_topic_name,
    ros_type_name,
)
from terrainml.stream.transports.ros2.types import MESSAGE_TYPES

log = logging.getLogger("terrainml.stream")

SOURCE_OPTIONS = ("qos", "discovery_s", "warmup_s", "reorder_s")
DISCOVERY_S = 2.0
WAITING_WARN_S = 10.0
#: a topic that lags the others by more than this (stamps, s) is no longer waited for, alive or not
MAX_WAIT_LAG_S = 1.0
#: how often the discovery of publications is read while serving, s
DISCOVERY_POLL_S = 1.0
TAKE_MAX = 256
#: the loop's longest wait for a message, s (a pass later than this is the process's own lag)
WAIT_S = 0.1
#: key of the sample's ROS time origin (ns): ROS time = stamp_origin_ns + t_s
STAMP_ORIGIN_KEY = "stamp_origin_ns"


class Ros2SourceError(ValueError):
    """The ROS 2 source cannot start (the message names the topic and types)."""


@dataclass
class _Sub:
    src: Source
    reader: DataReader
    dds_type: str


def _float_opt(opts: dict[str, str], key: str, default: float, spec: str) -> float:
    try:
        v = float(opts.get(key, default))
    except ValueError:
        raise Ros2SourceError(f"{spec}: option {key} must be a number, got {opts[key]!r}") from None
    if not v >= 0:
        raise Ros2SourceError(f"{spec}: option {key} must be >= 0, got {v}")
    return v


def _subscribe(dp: DomainParticipant, tmap: TopicMap, default_qos: str, spec: str) -> list[_Sub]:
    subs = []
    for src in tmap.sources:
        cls = MESSAGE_TYPES.get(src.type)
        if cls is None or cdr.KIND_OF_TYPE.get(src.type) != src.decode_kind:
            raise Ros2SourceError(f"{spec}: topic {src.topic}: type {src.type or '(none)'} of kind {src.kind} "
                                  f"cannot be subscribed (types: {', '.join(sorted(cdr.KIND_OF_TYPE))})")
        profile = str(src.options.get("qos", default_qos))
        if profile not in QOS_PROFILES:
            raise Ros2SourceError(f"{tmap.source_file}: topic {src.topic}: qos {profile!r} is not one of "
                                  f"{', '.join(QOS_PROFILES)}")
        topic = Topic(dp, dds_topic_name(src.topic), cls)
        subs.append(_Sub(src, DataReader(dp, topic, qos=qos_for(profile)), dds_type_name(src.type)))
    return subs


class _Discovery:
    """Publications seen on the domain (DDS built-in topic): who publishes which mapped topic, and
    publishers whose type differs from the map's."""

    def __init__(self, dp: DomainParticipant, subs: list[_Sub]):
        self.reader = BuiltinDataReader(dp, BuiltinTopicDcpsPublication)
        self.by_topic = {s.src.topic: s for s in subs}
        self.publishers: dict[str, int] = {}
        self.mismatched: dict[str, str] = {}
        self.graph: dict[str, str] = {}      # every ROS topic published on the domain -> its ROS type

    def poll(self) -> dict[str, str]:
        """Take new publications; returns the mismatches found this time (topic -> DDS type)."""
        new: dict[str, str] = {}
        for pub in self.reader.take(TAKE_MAX):
            name = getattr(pub, "topic_name", None)
            topic = ros_topic_name(name) if name else None
            if topic and not topic.startswith("/terrainml/") and topic != "/diagnostics":
                self.graph[topic] = ros_type_name(pub.type_name)
            sub = self.by_topic.get(topic) if topic else None
            if sub is None:
                continue
            if pub.type_name != sub.dds_type:
                if topic not in self.mismatched:
                    new[topic] = pub.type_name
                self.mismatched[topic] = pub.type_name
            else:
                self.publishers[topic] = self.publishers.get(topic, 0) + 1
        return new


def _mismatch_text(spec: str, by_topic: dict[str, _Sub], found: dict[str, str]) -> str:
    return "; ".join(f"{spec}: topic {topic} is published with type {ros_type_name(t)}, the topic map "
                     f"expects {by_topic[topic].src.type}" for topic, t in sorted(found.items()))


def _discover(disc: _Discovery, subs: list[_Sub], spec: str, discovery_s: float) -> None:
    """Look for publishers for ``discovery_s``: refuse mismatched types, warn about missing ones."""
    t_end = time.monotonic() + discovery_s
    required = [s.src.topic for s in subs if not s.src.options.get("optional")]
    while True:
        found = disc.poll()
        if found:
            raise Ros2SourceError(_mismatch_text(spec, disc.by_topic, found))
        if time.monotonic() >= t_end or all(t in disc.publishers for t in required):
            break
        time.sleep(0.05)
    for topic in required:
        if topic not in disc.publishers:
            log.warning("%s: no publisher on %s (%s) yet: waiting for it", spec, topic, disc.by_topic[topic].src.type)
    if not any(t in disc.publishers for t in required):
        _no_match_help(disc, subs, spec)


def fitting_maps(graph: dict[str, str]) -> list[str]:
    """The built-in topic maps whose every required topic is published with its type in ``graph``."""
    fits = []
    for name in BUILTIN_MAPS:
        tm = load_topic_map(name)
        need = [s for s in tm.sources if not s.options.get("optional")]
        if need and all(graph.get(s.topic) == s.type for s in need):
            fits.append(name)
    return fits


def _no_match_help(disc: _Discovery, subs: list[_Sub], spec: str) -> None:
    """No mapped topic has a publisher: what the DDS graph does publish, and the map that fits it."""
    disc.poll()
    if any(s.src.topic in disc.publishers for s in subs):
        return
    if not disc.graph:
        log.warning("%s: no ROS 2 topic is published on this domain (check ROS_DOMAIN_ID and the network, "
                    "docs/ros2.md)", spec)
        return
    listed = ", ".join(f"{t} ({ty})" for t, ty in sorted(disc.graph.items())[:40])
    fits = fitting_maps(disc.graph)
    hint = (f"; the built-in topic map {' / '.join(fits)} fits them: --topics {fits[0]}" if fits else
            "; no built-in topic map fits them: write one (docs/io.md) and pass --topics MAP.yaml")
    log.warning("%s: no mapped topic has a publisher; the domain publishes: %s%s", spec, listed, hint)


def _empty_fields(kind: str, msg: Any) -> frozenset[str]:
    """JointState fields the message left empty (the decoder fills them with NaN: not invalid)."""
    if kind != "joint_state":
        return frozenset()
    return frozenset(f for f in ("position", "velocity", "effort") if len(getattr(msg, f)) == 0)


def _take(subs: list[_Sub], use_header: bool, aligner: LiveAligner, spec: str,
          watch: InputWatch | None = None) -> int:
    """Every waiting message of every reader into the aligner; returns how many."""
    n = 0
    for sub in subs:
        while True:   # every reader emptied before the aligner decides a tick (a stall is not a lag)
            batch = sub.reader.take(TAKE_MAX)
            for msg in batch:
                info = getattr(msg, "sample_info", None)
                if info is not None and not info.valid_data:
                    continue
                log_ns = int(info.source_timestamp) if info is not None else time.time_ns()
                try:
                    part = cdr.from_object(sub.src.decode_kind, msg, log_ns, use_header)
                except cdr.LayoutError as exc:
                    log.warning("%s: topic %s: message skipped (%s)", spec, sub.src.topic, exc)
                    continue
                if watch is not None:
                    watch.on_message(sub.src.topic, part, empty=_empty_fields(sub.src.decode_kind, msg))
                aligner.add(sub.src.topic, part)
                n += 1
            if len(batch) < TAKE_MAX:
                break
    return n


def iter_ros2_samples(spec: str = "ros2://0", robot: RobotSpec | str | None = None, *,
                      topic_map: Any = None, rate_hz: float = DEFAULT_RATE_HZ,
                      idle_timeout_s: float | None = None, ready: Callable[[Any], None] | None = None,
                      counters: Any = None, max_gap_s: float = MAX_GAP_S, reanchor_after: int = REANCHOR_AFTER,
                      watch: InputWatch | None = None) -> Iterator[Sample]:
    """Typed samples from the ROS 2 topics of ``topic_map`` on the domain of ``spec`` (module docstring).

    Each aligned tick is checked once, as it is made (:func:`~terrainml.stream.tick.sample.typed_samples`;
    one that fails is counted in ``counters`` as malformed and skipped).

    Raises :class:`Ros2SourceError` before the first sample when the URL, the map or a publisher's
    type is wrong. ``counters`` (a :class:`~terrainml.stream.transports.sources.SourceCounters`) counts the
    messages received; its ``idle`` is set to the idle-timeout line when the stream ends on it.
    ``max_gap_s`` / ``reanchor_after``: the clock policy's G and K (``predict --max-clock-gap-s``,
    ``--reanchor-after``). ``watch``: per-topic freshness (:class:`~terrainml.stream.tick.inputs.InputWatch`;
    one is made when None), shared with a ROS 2 sink's ``/diagnostics``.
    """
    try:
        url = parse_url(spec, SOURCE_OPTIONS)
    except Ros2NameError as exc:
        raise Ros2SourceError(str(exc)) from None
    robot = load_robot(robot) if not isinstance(robot, RobotSpec) else robot
    tmap = load_topic_map(topic_map)
    default_qos = url.options.get("qos", "sensor_data")
    if default_qos not in QOS_PROFILES:
        raise Ros2SourceError(f"{spec}: qos must be one of {', '.join(QOS_PROFILES)}, got {default_qos!r}")
    discovery_s = _float_opt(url.options, "discovery_s", DISCOVERY_S, spec)
    aligner = LiveAligner(tmap, robot, rate_hz, name=spec,
                          warmup_s=_float_opt(url.options, "warmup_s", WARMUP_S, spec),
                          reorder_s=_float_opt(url.options, "reorder_s", REORDER_S, spec),
                          max_gap_s=max_gap_s, reanchor_after=reanchor_after)
    dp = DomainParticipant(url.domain_id)
    subs = _subscribe(dp, tmap, default_qos, spec)
    disc = _Discovery(dp, subs)
    _discover(disc, subs, spec, discovery_s)
    watch = watch if watch is not None else InputWatch()
    for sub in subs:
        watch.add_topic(sub.src.topic, sub.src.type, bool(sub.src.options.get("optional")))
    aligner.watch = watch
    if ready is not None:
        ready(None)
    return _serve(dp, subs, disc, aligner, tmap, spec, idle_timeout_s, counters, watch)


def _lagging_alive(aligner: LiveAligner, watch: InputWatch, subs: list[_Sub], now: float) -> bool:
    """A required topic whose stamps lag the others' by more than ``reorder_s`` (at most
    :data:`MAX_WAIT_LAG_S`) while it still delivers on the wall clock (not silent by its own
    timeout): its messages are on their way (a reader's queue, a retransmission, a loaded
    machine), so no tick is decided without it yet."""
    for sub in subs:
        if sub.src.options.get("optional"):
            continue
        lag = aligner.lag_s(sub.src.topic)
        if lag is None or not aligner.reorder_ns * 1e-9 < lag <= MAX_WAIT_LAG_S:
            continue
        age = watch.age_s(sub.src.topic, now)
        if age is not None and age <= watch.topics[sub.src.topic].timeout_s():
            return True
    return False


def _serve(dp: DomainParticipant, subs: list[_Sub], disc: _Discovery, aligner: LiveAligner, tmap: TopicMap,
           spec: str, idle_timeout_s: float | None, counters: Any, watch: InputWatch) -> Iterator[Sample]:
    count = counters.count_malformed if counters is not None else None
    ws = WaitSet(dp)
    for sub in subs:
        ws.attach(ReadCondition(sub.reader, SampleState.NotRead))
    use_header = tmap.stamp == "header"
    last_warn = last_disc = watch.started_s = time.monotonic()    # silence counts from here, not discovery
    flushed = False
    try:
        while True:
            ws.wait(duration(seconds=WAIT_S))
            watch.loop(WAIT_S)     # the process's own lag: silence restarts after it (inputs.py)
            n = _take(subs, use_header, aligner, spec, watch)
            now = time.monotonic()
            watch.update(now)
            if counters is not None:
                counters.received += n
            if now - last_disc >= DISCOVERY_POLL_S:     # publishers that appear later, with traffic or not
                last_disc = now
                found = disc.poll()
                if found:
                    log.error("%s", _mismatch_text(spec, disc.by_topic, found))
            flushed = flushed and not n
            if not n:
                idle = watch.idle_s(now)
                if idle >= FLUSH_AFTER_S and not flushed:    # every topic silent: no tick waits for them
                    flushed = True
                    for s in aligner.flush():
                        s[STAMP_ORIGIN_KEY] = aligner.t0_ns
                        yield from typed_samples((s,), count)
                if idle_timeout_s and idle >= idle_timeout_s:
                    line = (f"{spec}: idle timeout: no message for {idle:.1f} s (--idle-timeout-s "
                            f"{idle_timeout_s:g}); silent: {watch.silent_text(now)}")
                    log.warning("%s", line)
                    if counters is not None:
                        counters.idle = line
                    break
                if now - last_warn >= WAITING_WARN_S and idle >= WAITING_WARN_S:
                    log.warning("%s: no message for %.0f s; waiting for publishers on %s", spec,
                                idle, ", ".join(s.src.topic for s in subs))
                    _no_match_help(disc, subs, spec)
                    last_warn = now
            for s in aligner.poll(wait_all=watch.in_grace(now) or _lagging_alive(aligner, watch, subs, now)):
                s[STAMP_ORIGIN_KEY] = aligner.t0_ns
                yield from typed_samples((s,), count)
        for s in aligner.finish():
            s[STAMP_ORIGIN_KEY] = aligner.t0_ns
            yield from typed_samples((s,), count)
    finally:
        st = aligner.stats()
        if st["late"] or st["off_timeline"] or st["ignored"]:
            log.warning("%s: late messages %s, off-timeline %s, unused topics %s", spec, st["late"] or 0,
                        st["off_timeline"] or 0, st["ignored"] or 0)
        del ws, disc, subs, dp
