"""Where served :class:`DesiredSlip` messages go: stdout, UDP JSON, CAN, MCAP, Foxglove (design §11).

Sink specs (``terrainml predict --sink``; repeat the option for several sinks)::

    stdout                          one JSON object per line
    udp://HOST:PORT                 one JSON datagram per tick (default 127.0.0.1:9871)
    can://INTERFACE/CHANNEL         python-can, e.g. can://virtual/vcan0, can://socketcan/can0
    mcap:OUT.mcap                   MCAP recording, topic /terrainml/desired_slip, JSON schema
    ros2://DOMAIN                   ROS 2 topics over DDS: desired slip, terrain, diagnostics,
                                    slip-aware odometry (transports/ros2/sink.py, docs/ros2.md)
    foxglove://HOST:PORT            live view, Foxglove WebSocket server (default 127.0.0.1:8765;
                                    port 0 picks a free one); stream/transports/foxglove_sink.py

A sink that fails (socket error, CAN bus down, disk full, Foxglove port in use) is wrapped by :class:`GuardedSink`:
the error is logged (the first time and then every 1000th), counted, and the predictor goes on.

CAN frame layout (classic CAN, 11-bit ids, 8 data bytes, little endian; ``BASE`` default 0x300)
-----------------------------------------------------------------------------------------------
Summary frame, id ``BASE``::

    bytes 0-1  uint16  seq (mod 65536)
    byte  2    uint8   terrain_class (255 = none)
    byte  3    uint8   confidence x 250 (0..250)
    bytes 4-5  uint16  classification_age in ms (65535 = none or >= 65.5 s)
    byte  6    uint8   flags: bit0 fallback, bit1 estimator_ok, bits 2-7 fallback reason code
    byte  7    uint8   number of wheels N

Wheel frame i (1..N), id ``BASE + i``::

    bytes 0-1  int16   slip_desired x 1e4 (saturated to +-32767, i.e. +-3.2767)
    bytes 2-3  int16   slip_measured x 1e4 (-32768: not observable)
    byte  4    uint8   wheel state code: 0 idle, 1 steady, 2 traction, 3 braking
    byte  5    uint8   terrain_class (255 = none)
    byte  6    uint8   flags (as in the summary frame)
    byte  7    uint8   seq & 0xFF (pairs the wheel frames of one tick)

Fallback reason codes: 0 none, 1 estimator_unhealthy, 2 classifier_error, 3 no_classification,
4 stale_classification, 5 clock_jump, 6 uncertain_classification, 7 windows_rejected,
8 unknown_terrain (63: unknown; codes 1-6 keep the bits they had when the field was bits 2-4).
In fallback no class is served: ``terrain_class`` -1 is sent as 255. The message's
``fallback_detail``, ``sensors`` and ``novelty`` are not in the frames (JSON, UDP and MCAP
carry them).
"""

from __future__ import annotations

import json
import logging
import math
import os
import socket
import struct
import sys
from pathlib import Path
from typing import IO, Any, Protocol

import can
from mcap.writer import Writer

from terrainml.atomic import part_path
from terrainml.io.topics import WHEEL_STATE_CODES
from terrainml.stream.transports.foxglove_sink import DEFAULT_FOXGLOVE_SINK, FoxgloveSink, class_names_for
from terrainml.stream.tick.message import FALLBACK_REASONS, TOPIC, DesiredSlip, json_schema
from terrainml.stream.tick.sample import NO_SAMPLE, Sample
from terrainml.stream.transports.ros2.names import Ros2NameError, is_ros2_spec
from terrainml.stream.transports.ros2.sink import Ros2Sink

log = logging.getLogger("terrainml.stream")

DEFAULT_UDP_SINK = ("127.0.0.1", 9871)
CAN_BASE_ID = 0x300
#: CAN slip_measured when slip is not observable (int16 minimum; a real slip is clipped to +-32767)
SLIP_NA = -32768
REASON_CODES = {"": 0, **{r: i + 1 for i, r in enumerate(FALLBACK_REASONS)}}
_STATE_BY_CODE = {v: k for k, v in WHEEL_STATE_CODES.items()}
_REASON_BY_CODE = {v: k for k, v in REASON_CODES.items()}
#: code of a reason this table does not know (the 6 bits of the flags' reason field all set)
UNKNOWN_REASON_CODE = 63


class SinkError(ValueError):
    """A sink spec cannot be parsed or opened (the message names it)."""


class Sink(Protocol):
    name: str

    def send(self, msg: DesiredSlip, sample: Sample = NO_SAMPLE) -> None: ...

    def close(self) -> None: ...


# --------------------------------------------------------------------------- sinks
class StdoutSink:
    """One JSON object per line on ``stream`` (default stdout), flushed per message."""

    def __init__(self, stream: IO[str] | None = None):
        self.stream = stream or sys.stdout
        self.name = "stdout"

    def send(self, msg: DesiredSlip, sample: Sample = NO_SAMPLE) -> None:
        self.stream.write(msg.to_json() + "\n")
        self.stream.flush()

    def close(self) -> None:
        try:
            self.stream.flush()
        except Exception:  # noqa: BLE001 - closed pipe at exit
            pass


class UdpSink:
    """One JSON datagram per message to ``host:port``."""

    def __init__(self, host: str = DEFAULT_UDP_SINK[0], port: int = DEFAULT_UDP_SINK[1]):
        self.addr = (host, int(port))
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.name = f"udp://{host}:{port}"

    def send(self, msg: DesiredSlip, sample: Sample = NO_SAMPLE) -> None:
        self.sock.sendto(msg.to_json().encode(), self.addr)

    def close(self) -> None:
        self.sock.close()


def encode_can_frames(msg: DesiredSlip | dict, base_id: int = CAN_BASE_ID) -> list[tuple[int, bytes]]:
    """The frames of one message as (arbitration id, 8 data bytes); layout in the module doc."""
    d = msg.to_dict() if isinstance(msg, DesiredSlip) else msg
    n = len(d["slip_desired"])
    cls = d["terrain_class"] if 0 <= d["terrain_class"] < 255 else 255
    flags = (1 if d["fallback"] else 0) | (2 if d["estimator_ok"] else 0) \
        | (REASON_CODES.get(d["fallback_reason"], UNKNOWN_REASON_CODE) << 2)
    age = d["classification_age_s"]
    age_ms = 65535 if age < 0 else min(65535, int(round(age * 1e3)))
    conf = max(0, min(250, int(round(d["confidence"] * 250))))
    frames = [(base_id, struct.pack("<HBBHBB", d["seq"] & 0xFFFF, cls, conf, age_ms, flags, n & 0xFF))]

    def q(v: float) -> int:
        return max(-32767, min(32767, int(round(v * 1e4))))

    measured = d["slip_measured"]    # None: not observable (sent as SLIP_NA)
    for i in range(n):
        frames.append((base_id + i + 1, struct.pack(
            "<hhBBBB", q(d["slip_desired"][i]), SLIP_NA if measured is None else q(measured[i]),
            WHEEL_STATE_CODES.get(d["wheel_state"][i], 0), cls, flags, d["seq"] & 0xFF)))
    return frames


def decode_can_frames(frames: list[tuple[int, bytes]], base_id: int = CAN_BASE_ID) -> dict[str, Any]:
    """Inverse of :func:`encode_can_frames` (to the frame resolution); for receivers and tests."""
    by_id = {fid: data for fid, data in frames}
    seq, cls, conf, age_ms, flags, n = struct.unpack("<HBBHBB", by_id[base_id])
    out: dict[str, Any] = {
        "seq": seq, "terrain_class": None if cls == 255 else cls, "confidence": conf / 250,
        "classification_age_s": -1.0 if age_ms == 65535 else age_ms / 1e3,
        "fallback": bool(flags & 1), "estimator_ok": bool(flags & 2),
        "fallback_reason": _REASON_BY_CODE.get(flags >> 2, "unknown"),
        "slip_desired": [], "slip_measured": [], "wheel_state": [],
    }
    for i in range(n):
        sd, sm, st, _c, _f, _s = struct.unpack("<hhBBBB", by_id[base_id + i + 1])
        out["slip_desired"].append(sd / 1e4)
        out["slip_measured"].append(math.nan if sm == SLIP_NA else sm / 1e4)
        out["wheel_state"].append(_STATE_BY_CODE.get(st, "idle"))
    return out


class CanSink:
    """DesiredSlip as CAN frames through python-can (``interface`` e.g. virtual, socketcan)."""

    def __init__(self, interface: str, channel: str, base_id: int = CAN_BASE_ID, **bus_kwargs: Any):
        try:
            self.bus = can.Bus(interface=interface, channel=channel, **bus_kwargs)
        except Exception as exc:  # noqa: BLE001 - python-can raises many types
            raise SinkError(f"can://{interface}/{channel}: cannot open CAN bus ({exc})") from None
        self.base_id = int(base_id)
        self.name = f"can://{interface}/{channel}"

    def send(self, msg: DesiredSlip, sample: Sample = NO_SAMPLE) -> None:
        for fid, data in encode_can_frames(msg, self.base_id):
            self.bus.send(can.Message(arbitration_id=fid, data=data, is_extended_id=False))

    def close(self) -> None:
        self.bus.shutdown()


class _FlushedFile:
    """The MCAP writer's stream: every write reaches the OS at once (a full disk raises on the
    write of the chunk it loses, not at some later flush)."""

    def __init__(self, fh: IO[bytes]):
        self.fh = fh

    def write(self, data: bytes) -> int:
        n = self.fh.write(data)
        self.fh.flush()
        return n

    def tell(self) -> int:
        return self.fh.tell()


class SinkLost(SinkError):
    """A send that lost its tick and ``also_lost`` earlier ones (buffered, never written)."""

    def __init__(self, msg: str, also_lost: int = 0):
        super().__init__(msg)
        self.also_lost = also_lost


class McapSink:
    """MCAP recording: topic ``/terrainml/desired_slip``, JSON messages with a JSON schema.

    Foxglove plots e.g. ``/terrainml/desired_slip.slip_desired[0]`` directly. Log time is the
    tick's ``t_s`` (ns). The recording is written to ``.NAME.part`` and renamed onto ``NAME`` when
    it closes complete. A write failure (full disk) stops it: the send that meets it raises
    :class:`SinkLost` counting the ticks buffered in the unwritten chunk too, every later send
    raises (one lost tick each), and the cut recording is left as ``.NAME.part``, never as ``NAME``.
    """

    def __init__(self, path: str | Path, n_wheels: int | None = None, n_classes: int | None = None):
        self.path = Path(path)
        self.tmp = part_path(self.path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fh = open(self.tmp, "wb")
        self.writer = Writer(_FlushedFile(self._fh))  # type: ignore[arg-type]
        self.writer.start(profile="", library="terrainml")
        schema_id = self.writer.register_schema(
            name="terrainml.DesiredSlip", encoding="jsonschema",
            data=json.dumps(json_schema(n_wheels, n_classes)).encode())
        self.channel_id = self.writer.register_channel(
            topic=TOPIC, message_encoding="json", schema_id=schema_id)
        self.name = f"mcap:{self.path}"
        self._closed = False
        self._pending = 0       # ticks added since the last write reached the file
        self.failed: OSError | None = None

    def send(self, msg: DesiredSlip, sample: Sample = NO_SAMPLE) -> None:
        if self.failed is not None:
            raise SinkLost(f"{self.path}: recording stopped ({self.failed.strerror or self.failed})")
        t_ns = max(0, int(round(msg.t_s * 1e9)))
        before = self._fh.tell()
        try:
            self.writer.add_message(channel_id=self.channel_id, log_time=t_ns, publish_time=t_ns,
                                    data=msg.to_json().encode(), sequence=msg.seq & 0xFFFFFFFF)
        except OSError as exc:
            self.failed = exc
            lost, self._pending = self._pending, 0
            raise SinkLost(f"{self.path}: cannot write the recording ({exc.strerror or exc}); "
                           f"{lost + 1} ticks lost with this chunk, recording stopped",
                           also_lost=lost) from None
        self._pending = 0 if self._fh.tell() != before else self._pending + 1

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        if self.failed is None:
            try:
                self.writer.finish()
                self._fh.close()
                os.replace(self.tmp, self.path)
                return
            except OSError as exc:
                self.failed = exc
        try:
            self._fh.close()
        except OSError:
            pass
        raise SinkLost(f"{self.path}: recording incomplete ({self.failed.strerror or self.failed}); "
                       f"what was written is left as {self.tmp}", also_lost=self._pending)


class GuardedSink:
    """Wrap a sink so that its failures are logged and counted, never raised.

    ``errors`` counts lost ticks, not failed calls: a :class:`SinkLost` also takes back the
    ``also_lost`` ticks that were accepted (buffered) but never written, so ``sent + errors`` is
    the number of ticks offered. A warning is logged on the first failure and every
    ``log_every`` failures after it.
    """

    def __init__(self, sink: Any, log_every: int = 1000):
        self.sink = sink
        self.name = getattr(sink, "name", type(sink).__name__)
        self.errors = 0
        self.sent = 0
        self.failures = 0
        self.log_every = log_every

    def _lost(self, exc: Exception) -> int:
        lost = min(int(getattr(exc, "also_lost", 0)), self.sent)   # accepted earlier, never written
        self.sent -= lost
        self.errors += lost
        return lost

    def send(self, msg: DesiredSlip, sample: Sample = NO_SAMPLE) -> None:
        try:
            self.sink.send(msg, sample)
            self.sent += 1
        except Exception as exc:  # noqa: BLE001 - a sink that is down must not stop serving
            self.errors += 1
            self._lost(exc)
            self.failures += 1
            if self.failures == 1 or self.failures % self.log_every == 0:
                log.warning("sink %s failed (%d ticks lost so far; predictor continues): %s",
                            self.name, self.errors, exc)

    def close(self) -> None:
        try:
            self.sink.close()
        except Exception as exc:  # noqa: BLE001
            self._lost(exc)
            log.warning("sink %s failed to close (%d ticks lost in all): %s", self.name, self.errors, exc)


# --------------------------------------------------------------------------- factory
def _host_port(rest: str, default: tuple[str, int], spec: str, scheme: str = "udp") -> tuple[str, int]:
    if not rest:
        return default
    host, _, port = rest.rpartition(":")
    try:
        return (host or default[0], int(port))
    except ValueError:
        raise SinkError(f"sink {spec!r}: expected {scheme}://HOST:PORT") from None


def _scheme_rest(s: str, scheme: str) -> str | None:
    """What follows ``scheme://`` in ``s`` ("" for the bare scheme), or None for another scheme."""
    if s == scheme:
        return ""
    return s[len(scheme) + 3:] if s.startswith(scheme + "://") else None


def open_sink(spec: str, *, n_wheels: int | None = None, n_classes: int | None = None,
              class_names: list[str] | None = None, stdout: IO[str] | None = None,
              robot: Any = None, sensors: list[str] | None = None, watch: Any = None) -> GuardedSink:
    """Open one sink from its spec string (see the module docstring); raises SinkError.

    ``class_names`` names the class ids 0..K-1 where a sink shows names (Foxglove); default the
    eight classes of design §6.1. ``robot`` (wheel names and geometry) and ``sensors`` (the model's
    sensor groups) are what the ROS 2 sink states in its layout, odometry and diagnostics;
    ``watch`` (:class:`~terrainml.stream.tick.inputs.InputWatch`) gives its ``/diagnostics`` the input
    topics' freshness.
    """
    s = spec.strip()
    if s in ("stdout", "-"):
        sink: Any = StdoutSink(stdout)
    elif (rest := _scheme_rest(s, "udp")) is not None:
        host, port = _host_port(rest, DEFAULT_UDP_SINK, spec)
        sink = UdpSink(host, port)
    elif (rest := _scheme_rest(s, "foxglove")) is not None:
        host, port = _host_port(rest, DEFAULT_FOXGLOVE_SINK, spec, scheme="foxglove")
        if not 0 <= port <= 65535:
            raise SinkError(f"sink {spec!r}: port {port} out of range 0..65535 (0 picks a free one)")
        # a port that cannot be bound is not fatal: the sink retries and GuardedSink counts it
        sink = FoxgloveSink(host, port, n_wheels=n_wheels,
                            class_names=class_names_for(n_classes, class_names))
    elif is_ros2_spec(s):
        try:
            sink = Ros2Sink(s, robot, sensors, watch=watch)
        except Ros2NameError as exc:
            raise SinkError(f"sink {spec!r}: {exc}") from None
    elif s.startswith("can://"):
        iface, _, channel = s[len("can://"):].partition("/")
        if not iface or not channel:
            raise SinkError(f"sink {spec!r}: expected can://INTERFACE/CHANNEL, e.g. can://virtual/vcan0")
        sink = CanSink(iface, channel)
    elif s.startswith("mcap:"):
        path = s[len("mcap:"):]
        if not path:
            raise SinkError(f"sink {spec!r}: expected mcap:OUT.mcap")
        try:
            sink = McapSink(path, n_wheels, n_classes)
        except OSError as exc:
            raise SinkError(f"sink {spec!r}: cannot write {path} ({exc})") from None
    else:
        raise SinkError(f"unknown sink {spec!r}; expected stdout, udp://HOST:PORT, "
                        "can://INTERFACE/CHANNEL, mcap:OUT.mcap, foxglove://HOST:PORT or ros2://DOMAIN")
    return GuardedSink(sink)
