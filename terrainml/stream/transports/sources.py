"""Where base-rate samples come from: a log file, UDP JSON datagrams, stdin JSON lines (design §11).

A *sample* is a mapping of ``t_s`` and canonical run-table column names (design §5), e.g.
``{"t_s": 1.23, "wheel1_omega_radps": 6.1, ..., "imu_ax_mps2": 0.02, ...}``; missing groups,
``null`` or non-finite values simply make that sensor group invalid for the tick. Every source
checks each sample once, where it makes it (:func:`terrainml.stream.tick.sample.check_sample`),
and yields it typed (:class:`~terrainml.stream.tick.sample.Sample`): the JSON sources (UDP, stdin)
as they parse it, a log source per row of its run table, the ROS 2 source per aligned tick. One
that fails is counted in :class:`SourceCounters` and skipped.

Source specs (``terrainml predict --source``)::

    RUN.mcap | RUN.bag | RUN.parquet | RUN.csv   a recorded log (as fast as possible, or --realtime)
    BAG_FOLDER/                                  a ROS 2 bag folder (.mcap or .db3 inside)
    udp://HOST:PORT                              one JSON object per datagram (default 127.0.0.1:9870)
    -                                            JSON lines on stdin
    ros2://DOMAIN                                live ROS 2 topics over DDS (transports/ros2/source.py)

Log files are read through the io owner's ingest (:func:`terrainml.io.ingest.load_run`), i.e. the
very same topic decoding, frame mapping and resampling to the base rate as training used. A log
of another robot gets in the way ``terrainml ingest`` takes it: ``topic_map`` (``predict --topics``:
a topic map YAML or built-in name, :mod:`terrainml.io.topicmap`) says which topics and fields of an
MCAP/bag log feed which canonical columns, and ``dataset`` (``predict --format``: a dataset spec,
:mod:`terrainml.io.ingest.dataset_spec`) reads a CSV/Parquet file as one run of that dataset, with its
column names, units and scales (m/s wheel speeds become rad/s through the wheel radius, mA become
A, ms stamps become s) and its side-to-wheel mapping.
A datagram or line ``{"eos": true}`` ends the stream.

Parsing cannot be crashed (:func:`parse_sample`): every datagram or line is one UTF-8 JSON
object of at most :data:`MAX_SAMPLE_BYTES`, nested at most :data:`MAX_DEPTH` deep, whose numbers
all fit a finite float and whose ``t_s`` passes :func:`terrainml.stream.tick.sample.check_sample`.
Anything else is counted in :class:`SourceCounters` under one of :data:`MALFORMED_REASONS` and
skipped; nothing raises out of the source. The size cap is checked before parsing, nesting is
checked before ``json.loads`` (which also never sees more than the cap), and the number hooks of
``json.loads`` refuse an integer or float beyond float range and the non-JSON ``NaN`` /
``Infinity`` tokens (send ``null`` for a missing value). A ``RecursionError`` is caught as a
last resort. Values of the wrong type inside a well-formed sample (a string where a number
belongs) are not malformed: they invalidate their sensor group (:mod:`terrainml.stream.tick.health`).
"""

from __future__ import annotations

import json
import logging
import math
import re
import socket
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, Iterator

from terrainml.io.damage import DamageSummary, damage_summary
from terrainml.io.ingest import load_run
from terrainml.schema import DEFAULT_RATE_HZ, VALID_GROUPS, valid_column
from terrainml.stream.tick.clock import MAX_GAP_S, REANCHOR_AFTER
from terrainml.stream.transports.ros2.names import is_ros2_spec
from terrainml.stream.transports.ros2.source import Ros2SourceError, iter_ros2_samples
from terrainml.stream.tick.sample import InvalidSample, Sample, check_sample, typed_samples

log = logging.getLogger("terrainml.stream")

DEFAULT_UDP_SOURCE = ("127.0.0.1", 9870)
#: largest datagram or line parsed, bytes (characters for str input); a sample of a six-wheel
#: robot with simulator truth is about 3 KiB
MAX_SAMPLE_BYTES = 16 * 1024
#: deepest JSON nesting accepted (a sample is one flat object: depth 1)
MAX_DEPTH = 16
#: more digits than this cannot fit a float (1.8e308 has 309): refused before ``int()`` runs
_MAX_INT_DIGITS = 310
#: why a datagram or line was skipped (keys of ``SourceCounters.malformed_by_reason``)
MALFORMED_REASONS: tuple[str, ...] = (
    "too_large",            # over MAX_SAMPLE_BYTES
    "not_utf8",             # binary data
    "not_json",             # a syntax error
    "too_deep",             # nested deeper than MAX_DEPTH
    "number_out_of_range",  # an integer or float beyond float range (1e400, 10**400)
    "non_finite",           # NaN / Infinity / -Infinity tokens (not JSON)
    "not_an_object",        # a list, a number, a string, null
    "no_t_s",               # an object without "t_s"
    "bad_t_s",              # t_s not a number (a string, a bool, null, ...)
    "t_s_not_finite",       # a log row's or live tick's t_s is NaN or infinite
    "not_a_mapping",        # a log or live source made something that is not a mapping
    "bad_key",              # ... or one with a key that is not a str
)
# a JSON string (possibly unterminated) or one bracket: consumed left to right in linear time
_TOKENS = re.compile(r'"(?:[^"\\]|\\.)*"?|[\[\]{}]', re.S)


class SourceError(ValueError):
    """A source spec cannot be opened (the message names the file or address)."""


@dataclass
class SourceCounters:
    """Datagrams / lines received and skipped as malformed (in total and by reason)."""

    received: int = 0
    malformed: int = 0
    malformed_by_reason: dict[str, int] = field(default_factory=dict)
    damage: DamageSummary | None = None   # what a recorded log's ingest could not read
    idle: str | None = None   # the line saying why a live source ended on --idle-timeout-s

    def count_malformed(self, reason: str, data: Any) -> None:
        """Count one skipped input; warn for the first 3, then every 1000th."""
        self.malformed += 1
        self.malformed_by_reason[reason] = self.malformed_by_reason.get(reason, 0) + 1
        if self.malformed <= 3 or self.malformed % 1000 == 0:
            head = data[:80] if isinstance(data, (str, bytes, bytearray)) else repr(data)[:80]
            log.warning("malformed sample skipped (%s; %d so far): %.80r", reason, self.malformed, head)

    def as_dict(self) -> dict[str, Any]:
        return {"received": self.received, "malformed": self.malformed,
                "malformed_by_reason": dict(self.malformed_by_reason),
                "damage": self.damage.to_dict() if self.damage is not None else None}


_EOS = object()


class _Malformed(Exception):
    """Raised inside the parser (also from json.loads' hooks) with one of MALFORMED_REASONS."""

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


def _parse_int(text: str) -> int:
    if len(text) > _MAX_INT_DIGITS:
        raise _Malformed("number_out_of_range")
    value = int(text)
    try:
        float(value)
    except OverflowError:
        raise _Malformed("number_out_of_range") from None
    return value


def _parse_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):  # 1e400 parses as inf
        raise _Malformed("number_out_of_range")
    return value


def _parse_constant(text: str) -> float:
    raise _Malformed("non_finite")


def _nesting_ok(text: str) -> bool:
    """True if no bracket outside a string is nested deeper than MAX_DEPTH."""
    if text.count("[") + text.count("{") <= MAX_DEPTH:  # the common case, in C
        return True
    depth = 0
    for m in _TOKENS.finditer(text):
        tok = m.group()
        if tok[0] == '"':
            continue
        depth += 1 if tok in "[{" else -1
        if depth > MAX_DEPTH:
            return False
    return True


def _decode(data: Any, max_bytes: int) -> str:
    if len(data) > max_bytes:
        raise _Malformed("too_large")
    if isinstance(data, str):
        return data
    try:
        return bytes(data).decode("utf-8-sig")
    except (UnicodeDecodeError, TypeError):
        raise _Malformed("not_utf8") from None


def _parse(data: Any, max_bytes: int) -> Any:
    text = _decode(data, max_bytes)
    if not _nesting_ok(text):
        raise _Malformed("too_deep")
    try:
        obj = json.loads(text, parse_int=_parse_int, parse_float=_parse_float,
                         parse_constant=_parse_constant)
    except RecursionError:  # last resort: _nesting_ok should have refused it
        raise _Malformed("too_deep") from None
    except ValueError:  # JSONDecodeError, and int()'s digit limit
        raise _Malformed("not_json") from None
    if not isinstance(obj, dict):
        raise _Malformed("not_an_object")
    if obj.get("eos") is True:
        return _EOS
    try:
        check_sample(obj)
    except InvalidSample as exc:
        raise _Malformed(exc.reason) from None
    return obj


def parse_sample(data: bytes | str, counters: SourceCounters | None = None, *,
                 max_bytes: int = MAX_SAMPLE_BYTES) -> Any:
    """Parse one datagram or line into a sample dict; None if malformed (counted); _EOS at end.

    Never raises (module docstring): a malformed input is counted in ``counters`` under its
    reason (:data:`MALFORMED_REASONS`) and skipped.
    """
    if counters is not None:
        counters.received += 1
    try:
        return _parse(data, max_bytes)
    except _Malformed as exc:
        if counters is not None:
            counters.count_malformed(exc.reason, data)
        return None


# --------------------------------------------------------------------------- log files
def iter_log_samples(path: str | Path, robot: Any = None, *, rate_hz: float = DEFAULT_RATE_HZ,
                     realtime: bool = False, topic_map: Any = None, dataset: Any = None,
                     counters: SourceCounters | None = None, watch: Any = None) -> Iterator[Sample]:
    """Samples of a recorded log at the base rate (ingest + resampling of the io owner).

    ``topic_map`` and ``dataset`` are :func:`terrainml.io.ingest.load_run`'s: a topic map (name,
    YAML path or dict) for an MCAP/bag log, a dataset spec (built-in name, YAML path or dict) for
    a CSV/Parquet file of one run (module docstring); None: the defaults of ``terrainml ingest``.
    With ``realtime`` each sample is released at its ``t_s`` relative to the start (wall clock).
    Ingest's warnings (a mapped topic not in the log, ...) are logged before the first sample.
    ``watch`` (:class:`~terrainml.stream.tick.inputs.InputWatch`) is told the sensor groups the log
    has at all (``mapped_groups``): a group no row of the log has is *not mapped*, so the predictor
    serves on the sensors there from the first tick instead of calling that group silent.
    What ingest could not read (corrupt messages, bad cells, a truncated tail) is warned about
    before the first sample and kept in ``counters.damage`` for the end-of-run summary; the ticks
    it left without data are invalid in the table, so they are served as flagged fallbacks.
    """
    path = Path(path)
    if not path.exists():
        raise SourceError(f"{path}: file not found")
    try:
        res = load_run(path, robot=robot, topic_map=topic_map, rate_hz=rate_hz, dataset=dataset)
    except Exception as exc:  # noqa: BLE001 - ingest raises named errors; report them cleanly
        raise SourceError(f"{path}: cannot read log ({exc})") from None
    report = getattr(res, "report", None)
    if report is not None and getattr(report, "usable", True) is False:
        why = list(getattr(report, "errors", []) or []) + list(getattr(report, "warnings", []) or [])
        raise SourceError(f"{path}: log is not usable ({'; '.join(map(str, why)) or 'no usable table'})")
    for warning in getattr(report, "warnings", None) or []:  # e.g. a mapped topic not in the log
        log.warning("%s", warning)
    damage = damage_summary(res.table)
    if counters is not None:
        counters.damage = damage
    if watch is not None:  # a group no row of the whole log has is not mapped, never "silent"
        valid = {g: valid_column(g).name for g in VALID_GROUPS}
        watch.mapped_groups = [g for g, col in valid.items() if col in res.table.columns and bool(res.table[col].any())]
    if damage.any:
        log.warning("%s: %s", path, damage.text)
    yield from iter_table_samples(res.table, realtime=realtime, counters=counters)


def iter_table_samples(table: Any, *, realtime: bool = False,
                       counters: SourceCounters | None = None) -> Iterator[Sample]:
    """Rows of a run table (DataFrame) as typed samples, optionally paced at their ``t_s``.

    Each row is checked once (:func:`~terrainml.stream.tick.sample.typed_samples`); a row whose
    ``t_s`` is missing or not finite is counted in ``counters`` (malformed) and skipped.
    """
    count = counters.count_malformed if counters is not None else None
    t0_wall = None
    t0 = None
    for sample in typed_samples(_table_rows(table), count):
        if realtime:
            t = sample.t_s
            if t0_wall is None:
                t0_wall, t0 = time.perf_counter(), t
            delay = (t - t0) - (time.perf_counter() - t0_wall)
            if delay > 0:
                time.sleep(delay)
        yield sample


def _table_rows(table: Any) -> Iterator[dict[str, Any]]:
    """Rows of a DataFrame as dicts of Python scalars (numpy scalars unwrapped)."""
    cols = [str(c) for c in table.columns]
    for values in table.itertuples(index=False, name=None):
        sample = {}
        for c, v in zip(cols, values):
            if hasattr(v, "item"):
                v = v.item()
            sample[c] = v
        yield sample


# --------------------------------------------------------------------------- udp / stdin
def bind_udp(host: str, port: int) -> socket.socket:
    """A UDP socket bound to ``host:port`` with a large receive buffer; raises SourceError."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 * 2**20)
    except OSError:
        pass
    try:
        sock.bind((host, int(port)))
    except OSError as exc:
        sock.close()
        raise SourceError(f"udp://{host}:{port}: cannot bind ({exc})") from None
    return sock


def iter_udp_samples(host: str = DEFAULT_UDP_SOURCE[0], port: int = DEFAULT_UDP_SOURCE[1], *,
                     counters: SourceCounters | None = None, idle_timeout_s: float | None = None,
                     sock: socket.socket | None = None, ready: Any = None) -> Iterator[Sample]:
    """Typed samples from JSON datagrams on ``host:port`` until ``{"eos": true}`` or ``idle_timeout_s``."""
    counters = counters if counters is not None else SourceCounters()
    if sock is None:
        sock = bind_udp(host, port)
    sock.settimeout(idle_timeout_s if idle_timeout_s else None)
    if ready is not None:
        ready(sock.getsockname())
    try:
        while True:
            try:
                data, _ = sock.recvfrom(65535)
            except socket.timeout:
                counters.idle = (f"udp://{host}:{port}: idle timeout: no datagram for {idle_timeout_s:.1f} s "
                                 f"(--idle-timeout-s {idle_timeout_s:g})")
                log.warning("%s", counters.idle)
                return
            s = parse_sample(data, counters)
            if s is _EOS:
                return
            if s is not None:
                yield _typed(s)
    finally:
        sock.close()


def _bounded_lines(stream: IO[Any], max_bytes: int) -> Iterator[Any]:
    """Lines of ``stream`` (text or binary), none read whole if longer than ``max_bytes``.

    An over-long line yields its first ``max_bytes + 1`` characters (so the parser counts it as
    ``too_large``) and the rest of it is read and discarded in bounded pieces.
    """
    while True:
        line = stream.readline(max_bytes + 1)
        if not line:
            return
        if len(line) > max_bytes:
            tail = line
            while tail and tail[-1:] not in ("\n", b"\n"):
                tail = stream.readline(max_bytes + 1)
        yield line


def iter_line_samples(stream: IO[Any] | None = None, *, counters: SourceCounters | None = None,
                      max_bytes: int = MAX_SAMPLE_BYTES) -> Iterator[Sample]:
    """Typed samples from JSON lines (default stdin, read as bytes); blank lines are ignored."""
    counters = counters if counters is not None else SourceCounters()
    if stream is None:  # bytes: undecodable input is a malformed line, not a decoding error
        stream = getattr(sys.stdin, "buffer", sys.stdin)
    for line in _bounded_lines(stream, max_bytes):
        if not line.strip():
            continue
        s = parse_sample(line, counters, max_bytes=max_bytes)
        if s is _EOS:
            return
        if s is not None:
            yield _typed(s)


def _typed(sample: dict) -> Sample:
    """The typed sample of one :func:`parse_sample` has accepted (its ``t_s`` is checked)."""
    return Sample(float(sample["t_s"]), sample)


@dataclass(frozen=True)
class SourceOptions:
    """How ``--source`` is read, resolved once by the CLI (every default is ``terrainml predict``'s).

    Attributes
    ----------
    realtime : a log source is paced at its own time stamps (default: as fast as possible).
    idle_timeout_s : s, or None; a UDP or ROS 2 source ends after this long without input.
    rate_hz : Hz, the base rate a log or live source is resampled to.
    topic_map : how an MCAP/bag log or ROS 2 topics feed the canonical columns (a topic map name,
        YAML path or dict; :mod:`terrainml.io.topicmap`); None: the default map.
    dataset : how a CSV/Parquet log is read (a dataset spec; :mod:`terrainml.io.ingest.dataset_spec`).
    max_clock_gap_s, reanchor_after : the clock policy's G (s) and K, which the ROS 2 source's
        aligner applies as the predictor does (:mod:`terrainml.stream.tick.clock`).
    """

    realtime: bool = False
    idle_timeout_s: float | None = None
    rate_hz: float = DEFAULT_RATE_HZ
    topic_map: Any = None
    dataset: Any = None
    max_clock_gap_s: float = MAX_GAP_S
    reanchor_after: int = REANCHOR_AFTER


def open_source(spec: str, options: SourceOptions = SourceOptions(), *, robot: Any = None,
                counters: SourceCounters | None = None, ready: Any = None, watch: Any = None) -> Iterator[Sample]:
    """Iterator of samples for a ``--source`` spec (see the module docstring).

    ``options.topic_map`` / ``options.dataset``: how a log file is read (:func:`iter_log_samples`);
    refused (SourceError) for UDP and stdin, whose samples already carry canonical names.
    ``watch`` (:class:`~terrainml.stream.tick.inputs.InputWatch`, shared with the ROS 2 sink's
    ``/diagnostics``) reaches the ROS 2 source.
    """
    s = spec.strip()
    opt = options
    if (opt.topic_map is not None or opt.dataset is not None) and (s == "-" or s == "udp" or s.startswith("udp://")):
        raise SourceError(f"source {spec!r}: --topics and --format apply to a log file; UDP and stdin "
                          "samples carry canonical column names and SI units already")
    if s == "-":
        if ready is not None:
            ready(None)
        return iter_line_samples(counters=counters)
    if s.startswith("udp://") or s == "udp":
        rest = s[len("udp://"):] if s != "udp" else ""
        host, port = DEFAULT_UDP_SOURCE
        if rest:
            h, _, p = rest.rpartition(":")
            try:
                host, port = (h or host), int(p)
            except ValueError:
                raise SourceError(f"source {spec!r}: expected udp://HOST:PORT") from None
        sock = bind_udp(host, port)
        return iter_udp_samples(host, port, counters=counters, idle_timeout_s=opt.idle_timeout_s,
                                sock=sock, ready=ready)
    if is_ros2_spec(s):  # the topic map says which topics feed which columns, as for a log
        try:
            return iter_ros2_samples(s, robot, topic_map=opt.topic_map, rate_hz=opt.rate_hz, counters=counters,
                                     idle_timeout_s=opt.idle_timeout_s, ready=ready, watch=watch,
                                     max_gap_s=opt.max_clock_gap_s, reanchor_after=opt.reanchor_after)
        except (Ros2SourceError, ValueError) as exc:
            raise SourceError(str(exc)) from None
    path = Path(s)
    if not path.exists():
        raise SourceError(f"source {spec!r}: no such file (expected RUN.mcap, udp://HOST:PORT or -)")
    if ready is not None:
        ready(None)
    return iter_log_samples(path, robot, rate_hz=opt.rate_hz, realtime=opt.realtime, topic_map=opt.topic_map,
                            dataset=opt.dataset, counters=counters, watch=watch)
