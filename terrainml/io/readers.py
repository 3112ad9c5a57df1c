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
import yaml
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Message, Schema
from mcap.stream_reader import get_chunk_data_stream
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Reader as Rosbag2Reader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.msg import normalize_msgtype

from terrainml.io import cdr, ros1bag
from terrainml.io.rosbag2db import Db3Error, Db3File, open_db3

MCAP_MAGIC = b"\x89MCAP0\r\n"
BAG_MAGIC = b"#ROSBAG V2.0"
_HDR = struct.Struct("<BQ")            # MCAP record framing: opcode, body length
_MSG_HDR = struct.calcsize("<HIQQ")    # Message body before its data: channel, sequence, log/publish time
_COMPRESSIONS = ("", "zstd", "lz4")
_DAMAGE = (McapError, struct.error, UnicodeDecodeError)   # what parsing a damaged record raises
OnTimes = Callable[[str, np.ndarray], None]


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
    unread_bytes: int = 0            # truncated: bytes from the first incomplete record to the end
    missing_bytes: int = 0           # truncated: bytes the cut record declares beyond the end of the file
    incomplete_records: int = 0      # records cut short (top level and inside a cut chunk)
    recovered_from_cut: int = 0      # complete messages read from inside the cut record

    def truncation(self) -> dict[str, int] | None:
        """What a truncated file lost (None when the file is complete)."""
        if not self.truncated:
            return None
        return {"unread_bytes": self.unread_bytes, "missing_bytes": self.missing_bytes,
                "incomplete_records": self.incomplete_records, "recovered_from_cut": self.recovered_from_cut}

    def stat(self, topic: str) -> TopicStats:
        s = self.stats.get(topic)
        if s is None:
            s = self.stats[topic] = TopicStats(topic)
        return s


def is_rosbag2(path: Path) -> bool:
    """A ROS 2 bag folder: ``metadata.yaml`` beside its ``.db3`` or ``.mcap`` storage files."""
    return path.is_dir() and (path / "metadata.yaml").is_file()


def log_size(path: Path) -> int:
    """Bytes of a log file, or of every file of a ROS 2 bag folder."""
    if path.is_dir():
        return sum(p.stat().st_size for p in path.iterdir() if p.is_file())
    return os.path.getsize(path)


def sniff_format(path: Path) -> str:
    """'mcap', 'bag', 'rosbag2' (a bag folder), 'csv', 'parquet' from the magic bytes (extension as a
    fallback)."""
    if path.is_dir():
        if is_rosbag2(path):
            return "rosbag2"
        raise LogReadError(f"{path}: a folder but not a ROS 2 bag (no metadata.yaml)")
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
                 use_header_stamp: bool, on_times: OnTimes | None = None,
                 on_part: Callable[[str, dict], None] | None = None):
        self.topic, self.type, self.kind = topic, type_name, kind
        self.on_part, self.on_times = on_part, on_times
        self.res, self.block, self.hdr = res, block, use_header_stamp
        self.datas: list[bytes] = []
        self.times: list[int] = []
        self.stamp_buf: list[int] = []     # log times not yet handed to on_times (file order)
        self.stat = res.stat(topic)
        self.stat.type = type_name

    def stamps(self, log_ns: np.ndarray | None = None) -> None:
        """Hand the buffered log times, then ``log_ns``, to ``on_times`` (file order kept)."""
        if self.on_times is None:
            return
        if self.stamp_buf:
            self.on_times(self.topic, np.asarray(self.stamp_buf, np.int64))
            self.stamp_buf = []
        if log_ns is not None and len(log_ns):
            self.on_times(self.topic, log_ns)

    def add(self, data: bytes, log_ns: int) -> None:
        st = self.stat
        st.read += 1
        if st.first_ns is None or log_ns < st.first_ns:
            st.first_ns = log_ns
        if st.last_ns is None or log_ns > st.last_ns:
            st.last_ns = log_ns
        if self.on_times is not None:
            self.stamp_buf.append(log_ns)
            if len(self.stamp_buf) >= self.block:
                self.stamps()
        if self.kind is None:
            return
        self.datas.append(data)
        self.times.append(log_ns)
        if len(self.datas) >= self.block:
            self.flush()

    def add_view(self, view: "cdr.RowView", log_ns: np.ndarray) -> None:
        """n messages of equal length inside a decompressed chunk (vectorised path): decoded at once,
        so no chunk buffer outlives its chunk. Their log times go to ``on_times`` by the caller
        (:meth:`stamps`, once per chunk in file order)."""
        st = self.stat
        n = len(log_ns)
        st.read += n
        lo, hi = int(log_ns.min()), int(log_ns.max())
        st.first_ns = lo if st.first_ns is None else min(st.first_ns, lo)
        st.last_ns = hi if st.last_ns is None else max(st.last_ns, hi)
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


class McapScanner:
    """One pass over an MCAP file, record by record, in the manner of ``mcap.stream_reader.StreamReader``.

    The file's own framing (magic, then records of opcode, length and body) is followed to the end
    of the data section; one method per job: the record loop (:meth:`read`), a top-level record
    (:meth:`_top_level`), a Chunk (:meth:`_chunk`), its MessageIndex records
    (:meth:`_message_index`), decoding the pending chunk (:meth:`_process_chunk`: vectorised from
    its indexes, :meth:`_vectorised`, else record by record, :meth:`_walk`), a Schema, Channel or
    Message record (:meth:`_record`), a cut last record (:meth:`_truncated_tail`) and the closing
    counts (:meth:`_finish`). Damage handling: see the module docstring.

    Parameters: as :func:`read_mcap`.
    """

    def __init__(self, path: Path, wanted: Callable[[str, str], str | None], *, block: int = 4096,
                 use_header_stamp: bool = True, validate_crcs: bool = True, on_times: OnTimes | None = None,
                 progress: Callable[[int, int], None] | None = None,
                 on_part: Callable[[str, dict], None] | None = None):
        self.path = Path(path)
        self.wanted, self.block, self.hdr = wanted, block, use_header_stamp
        self.validate_crcs, self.on_times, self.progress, self.on_part = validate_crcs, on_times, progress, on_part
        self.res = ReadResult(path=self.path, format="mcap")
        self.size = os.path.getsize(self.path)
        self.schemas: dict[int, str] = {}            # schema id -> type name
        self.channels: dict[int, _TopicSink] = {}    # channel id -> its topic's sink
        self.pending: tuple[bytes, list] | None = None   # a decompressed chunk awaiting its message indexes
        self.bad_chunk = False                       # the last chunk was dropped: its indexes count the loss

    # -- the record loop
    def read(self) -> ReadResult:
        """Every record up to DataEnd/Footer (or the cut of a truncated file), then the closing counts."""
        res, size = self.res, self.size
        with open(self.path, "rb") as f:
            if f.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
                raise LogReadError(f"{self.path}: not an MCAP file (bad magic)")
            done = len(MCAP_MAGIC)
            while True:
                head = f.read(_HDR.size)
                if len(head) < _HDR.size:
                    res.truncated = True   # cut inside a record header, or no footer
                    res.unread_bytes = size - done
                    res.incomplete_records += bool(head)
                    break
                op, ln = _HDR.unpack(head)
                if ln > size - done - _HDR.size:   # runs past the end of the file: truncated (or a corrupt length)
                    res.unread_bytes = size - done
                    res.missing_bytes = done + _HDR.size + ln - size
                    res.incomplete_records += 1
                    self._truncated_tail(op, f.read())
                    break
                body = f.read(ln)
                done += _HDR.size + ln
                if self.progress is not None:
                    self.progress(done, size)
                if not self._top_level(op, body, done - _HDR.size - ln):
                    break
        self._process_chunk()
        return self._finish()

    def _top_level(self, op: int, body: bytes, offset: int) -> bool:
        """One record of the data section at byte ``offset``; False at its end (DataEnd, Footer)."""
        if op != Opcode.MESSAGE_INDEX:
            self._process_chunk()   # a chunk's indexes follow it: anything else means they are all read
        if op == Opcode.CHUNK:
            self._chunk(body, offset)
        elif op == Opcode.MESSAGE_INDEX:
            self._message_index(body)
        elif op in (Opcode.DATA_END, Opcode.FOOTER):
            return False
        else:
            self.bad_chunk = False
            try:
                self._record(op, body)
            except _DAMAGE:
                pass   # a damaged top-level record: only it is lost
        return True

    # -- chunks and their indexes
    def _chunk(self, body: bytes, offset: int) -> None:
        """Decompress a Chunk (CRC checked) and hold it until its message indexes are read."""
        try:
            buf = _chunk_bytes(body, self.validate_crcs)
        except Exception as exc:  # noqa: BLE001 - any damage drops this chunk only
            self.res.corrupt_chunks += 1
            self.res.warnings.append(f"{self.path}: corrupt chunk at byte {offset} ({exc}); "
                                     "its messages are counted as corrupt, reading goes on")
            self.bad_chunk = True
            return
        self.bad_chunk = False
        self.pending = (buf, [])

    def _message_index(self, body: bytes) -> None:
        """A MessageIndex: kept for the pending chunk, or the lost messages of a dropped one."""
        cid, ix = _message_index(body)
        if self.pending is not None:
            self.pending[1].append((cid, ix))
        elif self.bad_chunk:   # the indexes of a dropped chunk count its lost messages
            if cid in self.channels:
                self.channels[cid].stat.corrupt += len(ix)
            else:
                self.res.unattributed_corrupt += len(ix)

    def _process_chunk(self) -> None:
        """Decode the pending chunk: vectorised from its message indexes when it holds only
        messages of known channels, else by walking its records."""
        if self.pending is None:
            return
        buf, indexes = self.pending
        self.pending = None
        if not (indexes and all(cid in self.channels for cid, _ in indexes) and self._vectorised(buf, indexes)):
            self._walk(buf)
            for sink in self.channels.values():  # keep decoded parts in file order
                sink.flush()

    def _vectorised(self, buf: bytes, indexes: list) -> bool:
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
            per.append((self.channels[cid], t, off + _HDR.size + _MSG_HDR, ln - _MSG_HDR))
            total += int((_HDR.size + ln).sum())
        if total != len(buf):
            return False
        for sink, t, data_off, data_len in per:
            sink.stamps(t)
            for n in np.unique(data_len):
                sel = data_len == n
                sink.add_view(cdr.RowView(arr8, data_off[sel], int(n)), t[sel])
        return True

    def _walk(self, buf: bytes) -> None:
        """Every record of a decompressed chunk, in order; a record cut short ends the walk."""
        p, end = 0, len(buf)
        while p + _HDR.size <= end:
            op, ln = _HDR.unpack_from(buf, p)
            body = p + _HDR.size
            if body + ln > end:
                self.res.truncated = True
                self.res.incomplete_records += 1
                break
            if op in (Opcode.MESSAGE, Opcode.SCHEMA, Opcode.CHANNEL):
                try:
                    self._record(op, buf[body:body + ln])
                except _DAMAGE:
                    pass   # a damaged record: only it is lost
            p = body + ln

    # -- records
    def _record(self, op: int, body: bytes) -> None:
        """A Message, Schema or Channel record (top level or inside a chunk)."""
        if op == Opcode.MESSAGE:
            msg = _record(Message, body, len(body))
            sink = self.channels.get(msg.channel_id)
            if sink is None:
                self.res.unattributed_corrupt += 1
            else:
                sink.add(msg.data, msg.log_time)
        elif op == Opcode.SCHEMA:
            schema = _record(Schema, body)
            self.schemas[schema.id] = schema.name
        elif op == Opcode.CHANNEL:
            ch = _record(Channel, body)
            if ch.id not in self.channels:
                type_name = cdr.normalize_type(self.schemas.get(ch.schema_id, ""))
                self.channels[ch.id] = _TopicSink(ch.topic, type_name, self.wanted(ch.topic, type_name), self.res,
                                                  self.block, self.hdr, self.on_times, self.on_part)

    # -- the end
    def _truncated_tail(self, op: int, rest: bytes) -> None:
        """The last record runs past the end of the file: keep what a cut chunk still holds."""
        res = self.res
        res.truncated = True
        self._process_chunk()
        before = sum(st.read for st in res.stats.values())
        if op == Opcode.CHUNK:
            try:
                chunk = _record(Chunk, rest)   # its data: the bytes that are there
                self._walk(_partial_decompress(chunk.compression, chunk.data))
            except _DAMAGE:
                pass
        res.recovered_from_cut = sum(st.read for st in res.stats.values()) - before

    def _finish(self) -> ReadResult:
        """Flush every topic, count the skipped ones, and the truncation and lost-channel warnings."""
        res = self.res
        for sink in self.channels.values():
            sink.flush()
            sink.stamps()
            if sink.kind is None:
                sink.stat.skipped += sink.stat.read
            res.kinds[sink.topic] = sink.kind or ""
        if res.truncated:
            res.warnings.append(_truncation_warning(self.path, res))
        if res.unattributed_corrupt:
            res.warnings.append(f"{self.path}: {res.unattributed_corrupt} message(s) on channels whose definition "
                                "was lost (corrupt chunk) could not be attributed to a topic")
        return res


def read_mcap(path: Path, wanted: Callable[[str, str], str | None], *, block: int = 4096,
              use_header_stamp: bool = True, validate_crcs: bool = True, on_times: OnTimes | None = None,
              progress: Callable[[int, int], None] | None = None,
              on_part: Callable[[str, dict], None] | None = None) -> ReadResult:
    """Stream an MCAP file (one :class:`McapScanner` pass).

    Parameters
    ----------
    wanted : ``(topic, type) -> kind or None``; messages of topics mapped to None are only counted.
    block : messages per topic decoded at once (memory bound: block x message size per topic).
    progress : optional ``(bytes_done, bytes_total)`` callback.
    on_part : optional ``(topic, part)`` consumer of decoded parts, in file order; when given,
        ``ReadResult.parts`` stays empty (streaming ingest: nothing decoded is kept by the reader).
    on_times : optional ``(topic, log times ns (n,))`` consumer of every message's log time, per
        topic in file order, in blocks (``inspect``: nothing is kept by the reader).
    """
    return McapScanner(path, wanted, block=block, use_header_stamp=use_header_stamp, validate_crcs=validate_crcs,
                       on_times=on_times, progress=progress, on_part=on_part).read()


def _truncation_warning(path: Path, res: ReadResult) -> str:
    lost = f"{res.unread_bytes:,} byte(s) at the end unread" if res.unread_bytes else "no summary/footer"
    if res.missing_bytes:
        lost += f", {res.missing_bytes:,} byte(s) of the last record missing"
    if res.incomplete_records:
        lost += f", {res.incomplete_records} incomplete record(s)"
    return (f"{path}: file is truncated ({lost}); every complete message before the cut was kept"
            + (f" ({res.recovered_from_cut} from inside the cut record)" if res.recovered_from_cut else ""))


# ----------------------------------------------------------------------------- ROS 1 bag
class _BagTopics:
    """Per-topic counting and decoding of ROS 1 messages, shared by the indexed (rosbags) and the
    index-less (:mod:`terrainml.io.ros1bag`) paths."""

    def __init__(self, res: ReadResult, wanted, use_header_stamp: bool, on_times: OnTimes | None,
                 on_part: Callable[[str, dict], None] | None, deserialize: Callable[[bytes, str], object]):
        self.res, self.wanted, self.hdr = res, wanted, use_header_stamp
        self.on_times, self.on_part, self.deserialize = on_times, on_part, deserialize
        self.parts: dict[str, list] = {}
        self.stamps: dict[str, list[int]] = {}   # log times not yet handed to on_times

    def flush_stamps(self, topic: str | None = None) -> None:
        for tp in [topic] if topic is not None else list(self.stamps):
            if self.stamps.get(tp):
                self.on_times(tp, np.asarray(self.stamps.pop(tp), np.int64))

    def connection(self, topic: str, msgtype: str) -> str:
        """Register a topic; its decode kind ('' when only counted)."""
        if topic not in self.res.kinds:
            type_name = cdr.normalize_type(msgtype)
            self.res.stat(topic).type = type_name
            self.res.kinds[topic] = self.wanted(topic, type_name) or ""
        return self.res.kinds[topic]

    def message(self, topic: str, msgtype: str, log_ns: int, raw: bytes) -> None:
        st = self.res.stats[topic]
        st.read += 1
        st.first_ns = log_ns if st.first_ns is None else min(st.first_ns, log_ns)
        st.last_ns = log_ns if st.last_ns is None else max(st.last_ns, log_ns)
        if self.on_times is not None:
            buf = self.stamps.setdefault(topic, [])
            buf.append(log_ns)
            if len(buf) >= 4096:
                self.flush_stamps(topic)
        kind = self.res.kinds[topic]
        if not kind:
            st.skipped += 1
            return
        try:
            part = cdr.from_object(kind, self.deserialize(raw, msgtype), log_ns, self.hdr)
            st.decoded += 1
        except Exception:  # noqa: BLE001 - bytes that do not fit their type
            st.corrupt += 1
            return
        if part is not None:
            if self.on_part is None:
                self.parts.setdefault(topic, []).append(part)
            else:
                self.on_part(topic, part)


def read_bag(path: Path, wanted: Callable[[str, str], str | None], *, use_header_stamp: bool = True,
             on_times: OnTimes | None = None, progress: Callable[[int, int], None] | None = None,
             on_part: Callable[[str, dict], None] | None = None) -> ReadResult:
    """Read a ROS 1 bag, or a ROS 2 bag folder (``.db3`` or MCAP storage), message by message.

    A ROS 2 bag folder of uncompressed SQLite storage (``.db3``) is read row by row by
    :func:`_read_db3`, damaged or not (the intact rows of a truncated or damaged file are kept and
    the lost ones counted per topic); another ROS 2 bag folder is read with
    ``rosbags.rosbag2.Reader``; an indexed ROS 1 bag with rosbags'
    AnyReader (time order). A bag rosbags cannot open -- cut
    short, so its index is missing -- is read front to back by :func:`terrainml.io.ros1bag.scan_bag`
    (file order): every complete message before the cut is kept and what was lost is in
    ``ReadResult`` (``truncated``, ``unread_bytes``, ``missing_bytes``, ``incomplete_records``).

    ``on_part``/``on_times``: optional streaming consumers; see :func:`read_mcap`.
    """
    path = Path(path)
    storage = _db3_storage(path) if path.is_dir() else None
    if storage is not None:
        return _read_db3(path, *storage, _BagArgs(wanted, use_header_stamp, on_times, progress, on_part))
    if path.is_dir():
        res = ReadResult(path=path, format="rosbag2")
        reader, deserialize = _open_rosbag2(path)
    else:
        res = ReadResult(path=path, format="bag")
        try:
            reader = AnyReader([path])
            reader.open()
        except Exception as exc:  # noqa: BLE001 - rosbags raises several types
            return _read_bag_without_index(path, wanted, use_header_stamp, on_times, progress, on_part, exc)
        deserialize = reader.deserialize
    topics = _BagTopics(res, wanted, use_header_stamp, on_times, on_part, deserialize)
    try:
        conns = []
        for c in reader.connections:
            kind = topics.connection(c.topic, c.msgtype)
            if kind or on_times is not None:
                conns.append(c)
            else:
                st = res.stats[c.topic]
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
            topics.message(conn.topic, conn.msgtype, log_ns, raw)
            done += 1
            if progress is not None and done % 2000 == 0:
                progress(done, total)
    finally:
        reader.close()
    topics.flush_stamps()
    res.parts = topics.parts
    return res


def _open_rosbag2(path: Path):
    """A ROS 2 bag folder opened with ``rosbags.rosbag2.Reader`` (``.db3`` or MCAP storage), and a
    CDR deserialiser: standard types from rosbags' latest ROS 2 store, others from the definitions
    the bag carries."""
    try:
        reader = Rosbag2Reader(path)
        reader.open()
    except Exception as exc:  # noqa: BLE001 - rosbags raises several types
        raise LogReadError(f"{path}: not a readable ROS 2 bag folder ({exc})") from None
    typestore = get_typestore(Stores.LATEST)
    for c in reader.connections:
        if c.msgtype not in typestore.fielddefs and getattr(c.msgdef, "data", ""):
            try:
                typestore.register(get_types_from_msg(c.msgdef.data, c.msgtype))
            except Exception:  # noqa: BLE001 - an unreadable definition: its messages count as corrupt
                pass
    return reader, typestore.deserialize_cdr


def _read_bag_without_index(path: Path, wanted, use_header_stamp: bool, on_times: OnTimes | None,
                            progress, on_part, open_error: Exception) -> ReadResult:
    """A bag rosbags refused: scanned record by record; types from the bag's own definitions."""
    res = ReadResult(path=path, format="bag")
    typestore = get_typestore(Stores.EMPTY)
    registered: set[str] = set()

    def deserialize(raw: bytes, msgtype: str):
        return typestore.deserialize_ros1(raw, msgtype)

    topics = _BagTopics(res, wanted, use_header_stamp, on_times, on_part, deserialize)

    def on_message(conn: ros1bag.BagConnection, log_ns: int, raw: bytes) -> None:
        msgtype = normalize_msgtype(conn.msgtype)
        if topics.connection(conn.topic, msgtype) and msgtype not in registered:
            registered.add(msgtype)
            try:
                typestore.register(get_types_from_msg(conn.msgdef, msgtype))
            except Exception:  # noqa: BLE001 - a bad definition: its messages count as corrupt
                pass
        topics.message(conn.topic, msgtype, log_ns, raw)

    try:
        scan = ros1bag.scan_bag(path, on_message, progress)
    except ros1bag.BagFormatError as exc:
        raise LogReadError(f"{path}: not a readable ROS bag ({open_error}; record scan: {exc})") from None
    topics.flush_stamps()
    res.parts = topics.parts
    res.warnings.append(f"{path}: no usable bag index ({open_error}); read record by record")
    res.warnings.extend(scan.warnings)
    res.corrupt_chunks = scan.corrupt_chunks
    for cid, n in scan.lost_per_conn.items():
        c = scan.connections.get(cid)
        if c is None:
            res.unattributed_corrupt += n
        else:
            topics.connection(c.topic, normalize_msgtype(c.msgtype))
            res.stats[c.topic].corrupt += n
    res.unattributed_corrupt += scan.unattributed
    res.truncated = scan.truncated
    res.unread_bytes, res.missing_bytes = scan.unread_bytes, scan.missing_bytes
    res.incomplete_records, res.recovered_from_cut = scan.incomplete_records, scan.recovered_from_cut
    for c in scan.connections.values():   # connections defined but without a complete message
        topics.connection(c.topic, normalize_msgtype(c.msgtype))
    if res.truncated:
        res.warnings.append(_truncation_warning(path, res))
    return res


# ----------------------------------------------------------------------------- ROS 2 .db3 storage
@dataclass
class _BagArgs:
    """What :func:`read_bag` was asked for, handed on to the ``.db3`` reader."""

    wanted: Callable[[str, str], str | None]
    use_header_stamp: bool
    on_times: OnTimes | None
    progress: Callable[[int, int], None] | None
    on_part: Callable[[str, dict], None] | None


def _db3_storage(path: Path) -> tuple[list[Path], dict[str, int]] | None:
    """The ``.db3`` files of an uncompressed SQLite bag folder and its per-topic message counts
    from ``metadata.yaml`` (None: another storage, compressed, or metadata unreadable -- rosbags
    then reads the folder, or says why not)."""
    try:
        info = yaml.safe_load((path / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
        if info.get("storage_identifier") != "sqlite3" or str(info.get("compression_mode") or "none").lower() != "none":
            return None
        files = [path / Path(str(p)).name for p in info["relative_file_paths"]]
        counts: dict[str, int] = {}
        for t in info.get("topics_with_message_count") or []:
            name = t["topic_metadata"]["name"]
            counts[name] = counts.get(name, 0) + int(t["message_count"])
    except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError, AttributeError):
        return None
    if not files or not all(f.is_file() for f in files):
        return None
    return files, counts


def _read_db3(path: Path, files: list[Path], expected: dict[str, int], args: _BagArgs) -> ReadResult:
    """A ROS 2 bag folder of ``.db3`` files, read row by row (:mod:`terrainml.io.rosbag2db`).

    SQLite's own API (and rosbags on it) refuses a damaged database whole; reading rows one cursor
    step at a time and seeking past those that do not read keeps every intact row. What was lost
    goes into the same fields as MCAP damage: per-topic ``corrupt`` (the ``metadata.yaml`` count
    less the rows read), ``corrupt_chunks`` (unreadable row ranges), ``truncated`` and its bytes.
    Only a bag none of whose files can be read (not even the topics table) is refused
    (:class:`LogReadError` naming the file).
    """
    res = ReadResult(path=path, format="rosbag2")
    typestore = get_typestore(Stores.LATEST)
    topics = _BagTopics(res, args.wanted, args.use_header_stamp, args.on_times, args.on_part,
                        typestore.deserialize_cdr)
    total, done, opened, damaged, lost, garbled = max(sum(expected.values()), 1), 0, [], [], 0, 0
    for f in files:
        try:
            db = open_db3(f)
        except Db3Error as exc:
            res.warnings.append(str(exc))
            continue
        opened.append(f)
        try:
            _register_db3_types(db, typestore, topics)
            for _id, tid, log_ns, raw in db.rows():
                tp = db.topics.get(tid)
                if tp is None or not isinstance(log_ns, int) or not isinstance(raw, bytes):
                    garbled += 1         # a damaged page read as a row (no such topic, no data)
                    continue
                topics.message(tp[0], tp[1], log_ns, raw)
                done += 1
                if args.progress is not None and done % 2000 == 0:
                    args.progress(done, total)
        finally:
            db.close()
        lost += db.lost_rows
        if db.bad_ranges or db.truncated:
            damaged.append(f.name)
        _db3_file_damage(res, db)
    if not opened:
        raise LogReadError(f"{path}: not a readable ROS 2 bag folder ({'; '.join(res.warnings)})")
    topics.flush_stamps()
    res.parts = topics.parts
    _db3_losses(res, path, damaged, expected, lost + garbled)
    return res


def _register_db3_types(db: Db3File, typestore, topics: _BagTopics) -> None:
    """The file's topics registered for counting; types the store lacks from the file's own
    definitions (an unreadable definition: its messages count as corrupt)."""
    for name, msgtype in db.topics.values():
        topics.connection(name, msgtype)
        if msgtype not in typestore.fielddefs and db.msgdefs.get(msgtype):
            try:
                typestore.register(get_types_from_msg(db.msgdefs[msgtype], msgtype))
            except Exception:  # noqa: BLE001 - a bad definition: its messages count as corrupt
                pass


def _db3_file_damage(res: ReadResult, db: Db3File) -> None:
    """One storage file's unreadable ranges and truncation into the result (with a warning)."""
    res.corrupt_chunks += db.bad_ranges
    if db.truncated:
        res.truncated = True
        missing, partial = db.declared_bytes - db.file_bytes, db.file_bytes % db.page_size if db.page_size else 0
        res.missing_bytes += missing
        res.unread_bytes += partial
        res.incomplete_records += 1 if partial else 0
        res.warnings.append(f"{db.path}: file is truncated ({missing:,} of the {db.declared_bytes:,} byte(s) its "
                            f"header declares are missing); every row before the cut that reads was kept")


def _db3_losses(res: ReadResult, path: Path, damaged: list[str], expected: dict[str, int], lost_rows: int) -> None:
    """Per-topic lost rows (``metadata.yaml`` count less rows read) counted corrupt; lost rows
    beyond those (a topic the metadata does not count) unattributed; one warning naming the bag
    and the counts when anything was lost."""
    per_topic = {}
    for topic, n in expected.items():
        st = res.stats.get(topic)
        gone = n - (st.read if st is not None else 0)
        if gone > 0:
            res.stat(topic).corrupt += gone
            per_topic[topic] = gone
    res.unattributed_corrupt += max(lost_rows - sum(per_topic.values()), 0)
    if per_topic or res.corrupt_chunks or res.unattributed_corrupt:
        listed = ", ".join(f"{t} {n:,}" for t, n in sorted(per_topic.items()))
        n_lost = sum(per_topic.values()) + res.unattributed_corrupt
        res.warnings.append(
            f"{path}: damaged .db3 storage ({', '.join(damaged) or 'rows of unknown topics'}): {n_lost:,} "
            f"message(s) lost" + (f" ({listed})" if listed else "") + f" in {res.corrupt_chunks} unreadable "
            f"row range(s); every readable row was kept")
