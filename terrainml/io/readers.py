"""Streaming, damage-tolerant log readers: ROS 2 MCAP and ROS 1 bag.

Both yield the same thing: per topic, decoded numeric parts (see :mod:`terrainml.io.cdr`) plus
per-topic counts of messages read, corrupt and skipped, so ingest and inspect share one pass.

MCAP is read record by record with the file's own framing (magic, opcode, length), never the whole
log: chunks are decompressed one at a time, their CRC checked, messages buffered per topic in blocks
of ``block`` messages and decoded block-wise (vectorised). Damage handling:

* a chunk whose CRC does not match or that does not decompress is dropped whole; its messages are
  counted as corrupt per topic from the message-index records that follow it;
* a truncated file (the last record runs past the end) is decompressed as far as the bytes go
  (zstd/lz4 streaming) and every complete message in it is kept; the cut is reported;
* a message whose bytes do not fit its type is counted corrupt on its topic;
* a topic whose schema is not the type the topic map expects is skipped and counted.

Messages are not sorted here; ingest sorts per topic and counts out-of-order/duplicate stamps.
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path
from typing import Callable

import lz4.frame
import numpy as np
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Message, Schema
from mcap.stream_reader import get_chunk_data_stream
from rosbags.highlevel import AnyReader

from terrainml.io import cdr

MCAP_MAGIC = b"\x89MCAP0\r\n"
BAG_MAGIC = b"#ROSBAG V2.0"
_HDR = struct.Struct("<BQ")            # MCAP record framing: opcode, body length
_MSG_HDR = struct.calcsize("<HIQQ")    # Message body before its data: channel, sequence, log/publish time
_COMPRESSIONS = ("", "zstd", "lz4")
_DAMAGE = (McapError, struct.error, UnicodeDecodeError)   # what parsing a damaged record raises


class LogReadError(ValueError):
    """The file cannot be read as a log at all (the message names the file)."""


@dataclass
class TopicStats:
    topic: str
    type: str = ""
    read: int = 0            # messages whose bytes were read
    decoded: int = 0         # decoded into numbers
    corrupt: int = 0         # unreadable (bad chunk, bad bytes)
    skipped: int = 0         # deliberately not used (type mismatch, not mapped)
    first_ns: int | None = None
    last_ns: int | None = None
    times: list | None = None  # log times (ns) when the reader was asked to keep them


@dataclass
class ReadResult:
    path: Path
    format: str
    stats: dict[str, TopicStats] = field(default_factory=dict)
    parts: dict[str, list] = field(default_factory=dict)   # topic -> decoded parts
    kinds: dict[str, str] = field(default_factory=dict)    # topic -> decode kind
    warnings: list[str] = field(default_factory=list)
    truncated: bool = False
    corrupt_chunks: int = 0
    unattributed_corrupt: int = 0

    def stat(self, topic: str) -> TopicStats:
        s = self.stats.get(topic)
        if s is None:
            s = self.stats[topic] = TopicStats(topic)
        return s


def sniff_format(path: Path) -> str:
    """'mcap', 'bag', 'csv', 'parquet' from the magic bytes (extension as a fallback)."""
    try:
        with open(path, "rb") as f:
            head = f.read(16)
    except OSError as exc:
        raise LogReadError(f"{path}: cannot open ({exc.strerror})") from None
    if head.startswith(MCAP_MAGIC):
        return "mcap"
    if head.startswith(BAG_MAGIC):
        return "bag"
    if head.startswith(b"PAR1"):
        return "parquet"
    if not head:
        raise LogReadError(f"{path}: empty file (0 bytes), not a log")
    suffix = path.suffix.lower()
    if suffix in (".csv", ".txt", ".tsv"):
        return "csv"
    raise LogReadError(f"{path}: not a log (no MCAP, ROS 1 bag or Parquet magic; "
                       f"supported: .mcap, .bag, .csv, .parquet)")


# ----------------------------------------------------------------------------- MCAP
def _record(record_type, body: bytes, *args):
    """One ``mcap.records`` record parsed from its body bytes."""
    return record_type.read(ReadDataStream(BytesIO(body)), *args)


def _message_index(body: bytes) -> tuple[int, np.ndarray]:
    """Channel id and (n, 2) [log time ns, offset] entries of a MessageIndex record: the layout of
    ``mcap.records.MessageIndex``, its entries read as one array rather than a list of tuples."""
    stream = ReadDataStream(BytesIO(body))
    cid, n_bytes = stream.read2(), stream.read4()
    n = min(n_bytes, len(body) - stream.count) // 16
    return cid, np.frombuffer(body, "<u8", count=2 * n, offset=stream.count).reshape(-1, 2)


def _partial_decompress(compression: str, data: bytes) -> bytes:
    try:
        if compression == "zstd":
            return zstandard.ZstdDecompressor().decompressobj().decompress(data)
        if compression == "lz4":
            return lz4.frame.LZ4FrameDecompressor().decompress(data)
        return data
    except Exception:  # noqa: BLE001 - whatever came out before the damage is all there is
        return b""


def _chunk_bytes(body: bytes, validate_crc: bool) -> bytes:
    """The decompressed records of a Chunk record (``mcap.stream_reader`` checks the CRC)."""
    chunk = _record(Chunk, body)
    if chunk.compression not in _COMPRESSIONS:
        raise ValueError(f"unsupported chunk compression {chunk.compression!r}")
    stream, size = get_chunk_data_stream(chunk, validate_crc=validate_crc)
    return stream.read(size)   # the whole buffer: no copy


class _TopicSink:
    """Per-topic block buffer of raw messages; decodes a block when full (bounded memory)."""

    def __init__(self, topic: str, type_name: str, kind: str | None, res: ReadResult, block: int,
                 use_header_stamp: bool, keep_times: bool = False,
                 on_part: Callable[[str, dict], None] | None = None):
        self.topic, self.type, self.kind = topic, type_name, kind
        self.on_part = on_part
        self.res, self.block, self.hdr = res, block, use_header_stamp
        self.datas: list[bytes] = []
        self.times: list[int] = []
        self.stat = res.stat(topic)
        self.stat.type = type_name
        if keep_times:
            self.stat.times = []

    def add(self, data: bytes, log_ns: int) -> None:
        st = self.stat
        st.read += 1
        if st.first_ns is None or log_ns < st.first_ns:
            st.first_ns = log_ns
        if st.last_ns is None or log_ns > st.last_ns:
            st.last_ns = log_ns
        if st.times is not None:
            st.times.append(log_ns)
        if self.kind is None:
            return
        self.datas.append(data)
        self.times.append(log_ns)
        if len(self.datas) >= self.block:
            self.flush()

    def add_view(self, view: "cdr.RowView", log_ns: np.ndarray) -> None:
        """n messages of equal length inside a decompressed chunk (vectorised path): decoded at once,
        so no chunk buffer outlives its chunk."""
        st = self.stat
        n = len(log_ns)
        st.read += n
        lo, hi = int(log_ns.min()), int(log_ns.max())
        st.first_ns = lo if st.first_ns is None else min(st.first_ns, lo)
        st.last_ns = hi if st.last_ns is None else max(st.last_ns, hi)
        if st.times is not None:
            st.times.extend(log_ns.tolist())
        if self.kind is None:
            return
        parts, bad = cdr.decode_array(self.kind, self.type, view, log_ns, self.hdr)
        self._emit(parts)
        st.corrupt += bad
        st.decoded += n - bad

    def _emit(self, parts: list[dict]) -> None:
        if self.on_part is None:
            self.res.parts.setdefault(self.topic, []).extend(parts)
        else:  # streaming consumer: parts are handed over, never kept here
            for p in parts:
                self.on_part(self.topic, p)

    def flush(self) -> None:
        if self.datas:
            parts, bad = cdr.decode_block(self.kind, self.type, self.datas, np.asarray(self.times, np.int64),
                                          self.hdr)
            self._emit(parts)
            self.stat.corrupt += bad
            self.stat.decoded += len(self.datas) - bad
            self.datas, self.times = [], []



def read_mcap(path: Path, wanted: Callable[[str, str], str | None], *, block: int = 4096,
              use_header_stamp: bool = True, validate_crcs: bool = True, keep_times: bool = False,
              progress: Callable[[int, int], None] | None = None,
              on_part: Callable[[str, dict], None] | None = None) -> ReadResult:
    """Stream an MCAP file.

    Parameters
    ----------
    wanted : ``(topic, type) -> kind or None``; messages of topics mapped to None are only counted.
    block : messages per topic decoded at once (memory bound: block x message size per topic).
    progress : optional ``(bytes_done, bytes_total)`` callback.
    on_part : optional ``(topic, part)`` consumer of decoded parts, in file order; when given,
        ``ReadResult.parts`` stays empty (streaming ingest: nothing decoded is kept by the reader).
    """
    path = Path(path)
    res = ReadResult(path=path, format="mcap")
    size = os.path.getsize(path)
    schemas: dict[int, str] = {}
    channels: dict[int, _TopicSink] = {}

    def add_record(op: int, body: bytes) -> None:
        """A Message, Schema or Channel record (top level or inside a chunk)."""
        if op == Opcode.MESSAGE:
            msg = _record(Message, body, len(body))
            sink = channels.get(msg.channel_id)
            if sink is None:
                res.unattributed_corrupt += 1
            else:
                sink.add(msg.data, msg.log_time)
        elif op == Opcode.SCHEMA:
            schema = _record(Schema, body)
            schemas[schema.id] = schema.name
        elif op == Opcode.CHANNEL:
            ch = _record(Channel, body)
            if ch.id not in channels:
                type_name = cdr.normalize_type(schemas.get(ch.schema_id, ""))
                channels[ch.id] = _TopicSink(ch.topic, type_name, wanted(ch.topic, type_name), res, block,
                                             use_header_stamp, keep_times, on_part)

    def walk_records(buf: bytes) -> None:
        """Every record of a decompressed chunk, in order; a record cut short ends the walk."""
        p, end = 0, len(buf)
        while p + _HDR.size <= end:
            op, ln = _HDR.unpack_from(buf, p)
            body = p + _HDR.size
            if body + ln > end:
                res.truncated = True
                break
            if op in (Opcode.MESSAGE, Opcode.SCHEMA, Opcode.CHANNEL):
                try:
                    add_record(op, buf[body:body + ln])
                except _DAMAGE:
                    pass   # a damaged record: only it is lost
            p = body + ln

    pending: list = []  # [decompressed chunk, [(channel id, index entries), ...]] awaiting its indexes

    def process_chunk() -> None:
        """Decode the pending chunk: vectorised from its message indexes when it holds only
        messages of known channels, else by walking its records."""
        if not pending:
            return
        buf, indexes = pending
        pending.clear()
        if not (indexes and all(cid in channels for cid, _ in indexes) and _vectorised(buf, indexes)):
            walk_records(buf)
            for sink in channels.values():  # keep decoded parts in file order
                sink.flush()

    def _vectorised(buf: bytes, indexes: list) -> bool:
        """Decode a chunk's messages per channel and length at once; False (nothing decoded) when
        its message indexes do not account for every byte of it."""
        arr8 = np.frombuffer(buf, dtype=np.uint8)
        per, total = [], 0
        for cid, ix in indexes:
            if not len(ix):
                continue
            t, off = ix[:, 0].astype(np.int64), ix[:, 1].astype(np.int64)
            if int(off.max()) + _HDR.size + _MSG_HDR > len(buf):
                return False
            # the record length follows the opcode byte
            ln = arr8[(off + 1)[:, None] + np.arange(8)].copy().view("<u8")[:, 0].astype(np.int64)
            if not np.all(arr8[off] == Opcode.MESSAGE) or np.any(ln < _MSG_HDR) or \
                    int((off + _HDR.size + ln).max()) > len(buf):
                return False
            per.append((channels[cid], t, off + _HDR.size + _MSG_HDR, ln - _MSG_HDR))
            total += int((_HDR.size + ln).sum())
        if total != len(buf):
            return False
        for sink, t, data_off, data_len in per:
            for n in np.unique(data_len):
                sel = data_len == n
                sink.add_view(cdr.RowView(arr8, data_off[sel], int(n)), t[sel])
        return True

    def read_truncated_tail(op: int, rest: bytes) -> None:
        """The last record runs past the end of the file: keep what a cut chunk still holds."""
        res.truncated = True
        process_chunk()
        if op == Opcode.CHUNK:
            try:
                chunk = _record(Chunk, rest)   # its data: the bytes that are there
                walk_records(_partial_decompress(chunk.compression, chunk.data))
            except _DAMAGE:
                pass

    pending_bad_chunk = False
    with open(path, "rb") as f:
        if f.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
            raise LogReadError(f"{path}: not an MCAP file (bad magic)")
        done = len(MCAP_MAGIC)
        while True:
            head = f.read(_HDR.size)
            if len(head) < _HDR.size:
                res.truncated = True   # cut inside a record header, or no footer
                break
            op, ln = _HDR.unpack(head)
            if ln > size - done - _HDR.size:   # runs past the end of the file: truncated (or a corrupt length)
                read_truncated_tail(op, f.read())
                break
            body = f.read(ln)
            done += _HDR.size + ln
            if progress is not None:
                progress(done, size)
            if op != Opcode.MESSAGE_INDEX:
                process_chunk()
            if op == Opcode.CHUNK:
                try:
                    buf = _chunk_bytes(body, validate_crcs)
                except Exception as exc:  # noqa: BLE001 - any damage drops this chunk only
                    res.corrupt_chunks += 1
                    res.warnings.append(f"{path}: corrupt chunk at byte {done - _HDR.size - ln} ({exc}); "
                                        "its messages are counted as corrupt, reading goes on")
                    pending_bad_chunk = True
                    continue
                pending_bad_chunk = False
                pending.extend([buf, []])
            elif op == Opcode.MESSAGE_INDEX:
                cid, ix = _message_index(body)
                if pending:
                    pending[1].append((cid, ix))
                elif pending_bad_chunk:   # the indexes of a dropped chunk count its lost messages
                    if cid in channels:
                        channels[cid].stat.corrupt += len(ix)
                    else:
                        res.unattributed_corrupt += len(ix)
            elif op in (Opcode.DATA_END, Opcode.FOOTER):
                break
            else:
                pending_bad_chunk = False
                try:
                    add_record(op, body)
                except _DAMAGE:
                    pass   # a damaged top-level record: only it is lost
    process_chunk()
    for sink in channels.values():
        sink.flush()
        if sink.kind is None:
            sink.stat.skipped += sink.stat.read
        res.kinds[sink.topic] = sink.kind or ""
    if res.truncated:
        res.warnings.append(f"{path}: file is truncated (no summary/footer); every complete message "
                            "before the cut was kept")
    if res.unattributed_corrupt:
        res.warnings.append(f"{path}: {res.unattributed_corrupt} message(s) on channels whose definition "
                            "was lost (corrupt chunk) could not be attributed to a topic")
    return res


# ----------------------------------------------------------------------------- ROS 1 bag
def read_bag(path: Path, wanted: Callable[[str, str], str | None], *, use_header_stamp: bool = True,
             keep_times: bool = False, progress: Callable[[int, int], None] | None = None,
             on_part: Callable[[str, dict], None] | None = None) -> ReadResult:
    """Read a ROS 1 bag (or a ROS 2 bag folder) with rosbags' AnyReader, message by message.

    ``on_part``: optional ``(topic, one-row part)`` consumer (streaming ingest); see :func:`read_mcap`.
    """
    path = Path(path)
    res = ReadResult(path=path, format="bag")
    parts: dict[str, list] = {}
    try:
        reader = AnyReader([path])
        reader.open()
    except Exception as exc:  # noqa: BLE001 - rosbags raises several types
        raise LogReadError(f"{path}: not a readable ROS bag ({exc})") from None
    try:
        conns = []
        for c in reader.connections:
            type_name = cdr.normalize_type(c.msgtype)
            st = res.stat(c.topic)
            st.type = type_name
            kind = wanted(c.topic, type_name)
            res.kinds[c.topic] = kind or ""
            if keep_times:
                st.times = []
            if kind or keep_times:
                conns.append(c)
            else:
                st.skipped += c.msgcount
                st.read += c.msgcount
        total = sum(c.msgcount for c in conns) or 1
        done = 0
        it = reader.messages(connections=conns)
        while True:
            try:
                conn, log_ns, raw = next(it)
            except StopIteration:
                break
            except Exception as exc:  # noqa: BLE001 - a damaged bag chunk ends the readable part
                res.truncated = True
                res.warnings.append(f"{path}: reading stopped early ({exc}); messages before kept")
                break
            st = res.stats[conn.topic]
            st.read += 1
            st.first_ns = log_ns if st.first_ns is None else min(st.first_ns, log_ns)
            st.last_ns = log_ns if st.last_ns is None else max(st.last_ns, log_ns)
            if st.times is not None:
                st.times.append(log_ns)
            if not res.kinds[conn.topic]:
                st.skipped += 1
                continue
            try:
                msg = reader.deserialize(raw, conn.msgtype)
                part = cdr.from_object(res.kinds[conn.topic], msg, log_ns, use_header_stamp)
                st.decoded += 1
            except Exception:  # noqa: BLE001
                st.corrupt += 1
                part = None
            if part is not None:
                if on_part is None:
                    parts.setdefault(conn.topic, []).append(part)
                else:
                    on_part(conn.topic, part)
            done += 1
            if progress is not None and done % 2000 == 0:
                progress(done, total)
    finally:
        reader.close()
    res.parts = parts
    return res
