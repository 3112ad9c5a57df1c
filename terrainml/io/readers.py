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
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from terrainml.io import cdr

MCAP_MAGIC = b"\x89MCAP0\r\n"
BAG_MAGIC = b"#ROSBAG V2.0"
_OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK, _OP_MSG_INDEX, _OP_FOOTER, _OP_DATA_END = 3, 4, 5, 6, 7, 2, 15
_HDR = struct.Struct("<BQ")
_MSG = struct.Struct("<HIQQ")


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
def _str(buf: bytes, p: int) -> tuple[str, int]:
    n = struct.unpack_from("<I", buf, p)[0]
    return buf[p + 4:p + 4 + n].decode("utf-8", "replace"), p + 4 + n


def _partial_decompress(compression: str, data: bytes) -> bytes:
    try:
        if compression == "zstd":
            import zstandard

            return zstandard.ZstdDecompressor().decompressobj().decompress(data)
        if compression == "lz4":
            import lz4.frame

            return lz4.frame.LZ4FrameDecompressor().decompress(data)
        return data
    except Exception:  # noqa: BLE001 - whatever came out before the damage is all there is
        return b""


def _decompress(compression: str, data: bytes, size: int) -> bytes:
    if compression == "zstd":
        import zstandard

        return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
    if compression == "lz4":
        import lz4.frame

        return lz4.frame.decompress(data)
    if compression == "":
        return data
    raise ValueError(f"unsupported chunk compression {compression!r}")


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
    chan_topic: dict[int, tuple[str, int]] = {}
    pending_bad_chunk = False

    def add_channel(cid: int, topic: str, sid: int) -> None:
        if cid in channels:
            return
        type_name = cdr.normalize_type(schemas.get(sid, ""))
        kind = wanted(topic, type_name)
        channels[cid] = _TopicSink(topic, type_name, kind, res, block, use_header_stamp, keep_times, on_part)

    def handle_records(buf: bytes, start: int, end: int) -> None:
        p = start
        while p + 9 <= end:
            op, ln = _HDR.unpack_from(buf, p)
            body = p + 9
            if body + ln > end:
                res.truncated = True
                break
            if op == _OP_MESSAGE:
                cid, _seq, log_t, _pub = _MSG.unpack_from(buf, body)
                sink = channels.get(cid)
                if sink is None:
                    res.unattributed_corrupt += 1
                else:
                    sink.add(buf[body + 22:body + ln], log_t)
            elif op == _OP_SCHEMA:
                sid = struct.unpack_from("<H", buf, body)[0]
                name, _ = _str(buf, body + 2)
                schemas[sid] = name
            elif op == _OP_CHANNEL:
                cid, sid = struct.unpack_from("<HH", buf, body)
                topic, _ = _str(buf, body + 4)
                add_channel(cid, topic, sid)
            p = body + ln

    pending: list = []  # [decompressed chunk, [(channel id, index bytes), ...]] awaiting its indexes

    def process_chunk() -> None:
        """Decode the pending chunk: vectorised from its message indexes when it holds only
        messages of known channels, else by walking its records."""
        if not pending:
            return
        buf, indexes = pending
        pending.clear()
        if indexes and all(cid in channels for cid, _ in indexes):
            per = []
            total = 0
            for cid, rec in indexes:
                ix = np.frombuffer(rec, dtype="<u8").reshape(-1, 2)
                if len(ix):
                    per.append((cid, ix[:, 0].astype(np.int64), ix[:, 1].astype(np.int64)))
            arr8 = np.frombuffer(buf, dtype=np.uint8)
            ok = True
            lens = []
            for cid, t, off in per:
                if off.size and int(off.max()) + 31 > len(buf):
                    ok = False
                    break
                ln = arr8[(off + 1)[:, None] + np.arange(8)].copy().view("<u8")[:, 0].astype(np.int64)
                if not np.all(arr8[off] == _OP_MESSAGE) or np.any(ln < 22) or int((off + 9 + ln).max()) > len(buf):
                    ok = False
                    break
                lens.append(ln)
                total += int((9 + ln).sum())
            if ok and total == len(buf):
                for (cid, t, off), ln in zip(per, lens):
                    sink = channels[cid]
                    for L in np.unique(ln):
                        sel = ln == L
                        sink.add_view(cdr.RowView(arr8, off[sel] + 31, int(L) - 22), t[sel])
                return
        handle_records(buf, 0, len(buf))
        for sink in channels.values():  # keep decoded parts in file order
            sink.flush()

    with open(path, "rb") as f:
        if f.read(8) != MCAP_MAGIC:
            raise LogReadError(f"{path}: not an MCAP file (bad magic)")
        done = 8
        while True:
            head = f.read(9)
            if len(head) < 9:
                if head or done < size:
                    res.truncated = True
                else:
                    res.truncated = True  # no footer
                break
            op, ln = _HDR.unpack(head)
            if ln > size - done - 9:
                # record runs past the end of the file: truncated (or a corrupt length)
                res.truncated = True
                process_chunk()
                rest = f.read()
                if op == _OP_CHUNK and len(rest) > 32:
                    try:
                        comp, p = _str(rest, 28)
                        data = rest[p + 8:]
                        buf = _partial_decompress(comp, data)
                        handle_records(buf, 0, len(buf))
                    except (struct.error, UnicodeDecodeError):
                        pass
                break
            body = f.read(ln)
            done += 9 + ln
            if progress is not None:
                progress(done, size)
            if op != _OP_MSG_INDEX:
                process_chunk()
            if op == _OP_CHUNK:
                pending_bad_chunk = False
                try:
                    _s, _e, usize, crc = struct.unpack_from("<QQQI", body, 0)
                    comp, p = _str(body, 28)
                    clen = struct.unpack_from("<Q", body, p)[0]
                    data = body[p + 8:p + 8 + clen]
                    buf = _decompress(comp, data, usize)
                    if validate_crcs and crc != 0 and zlib.crc32(buf) != crc:
                        raise ValueError("CRC mismatch")
                except Exception as exc:  # noqa: BLE001 - any damage drops this chunk only
                    res.corrupt_chunks += 1
                    res.warnings.append(f"{path}: corrupt chunk at byte {done - 9 - ln} ({exc}); "
                                        "its messages are counted as corrupt, reading goes on")
                    pending_bad_chunk = True
                    continue
                pending.extend([buf, []])
            elif op == _OP_MSG_INDEX:
                if pending:
                    cid = struct.unpack_from("<H", body, 0)[0]
                    n = struct.unpack_from("<I", body, 2)[0]
                    pending[1].append((cid, body[6:6 + n]))
                elif pending_bad_chunk:
                    cid = struct.unpack_from("<H", body, 0)[0]
                    n = struct.unpack_from("<I", body, 2)[0] // 16
                    if cid in channels:
                        channels[cid].stat.corrupt += n
                    else:
                        res.unattributed_corrupt += n
            elif op in (_OP_MESSAGE, _OP_SCHEMA, _OP_CHANNEL):
                pending_bad_chunk = False
                handle_records(head + body, 0, 9 + ln)
            elif op in (_OP_DATA_END, _OP_FOOTER):
                break
            else:
                pending_bad_chunk = False
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
    from rosbags.highlevel import AnyReader

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
