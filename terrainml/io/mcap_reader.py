"""Streaming, damage-tolerant ROS 2 MCAP reader.

MCAP is read record by record with the file's own framing (magic, opcode, length), never the whole
log: chunks are decompressed one at a time, their CRC checked, messages buffered per topic in blocks
of ``block`` messages and decoded block-wise (vectorised). Damage handling:

* a chunk whose CRC does not match or that does not decompress is dropped whole; its messages are
  counted as corrupt per topic from the message-index records that follow it;
* a truncated file (the last record runs past the end) is decompressed as far as the bytes go
  (zstd/lz4 streaming) and every complete message in it is kept; the cut is reported;
* a message whose bytes do not fit its type is counted corrupt on its topic;
* a topic whose schema is not the type the topic map expects is skipped and counted.
"""

from __future__ import annotations

import os
import struct
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

from terrainml.io import cdr
from terrainml.io.read_result import LogReadError, OnTimes, ReadResult, truncation_warning

__all__ = ["MCAP_MAGIC", "McapScanner", "read_mcap"]

MCAP_MAGIC = b"\x89MCAP0\r\n"
_HDR = struct.Struct("<BQ")            # MCAP record framing: opcode, body length
_MSG_HDR = struct.calcsize("<HIQQ")    # Message body before its data: channel, sequence, log/publish time
_COMPRESSIONS = ("", "zstd", "lz4")
_DAMAGE = (McapError, struct.error, UnicodeDecodeError)   # what parsing a damaged record raises


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
            res.warnings.append(truncation_warning(self.path, res))
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
