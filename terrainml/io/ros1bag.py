"""Front-to-back record scanner for ROS 1 bags (format 2.0) whose index is missing (design §5).

Hand-written on purpose: rosbags' reader opens a bag through its index (the connection and
chunk-info records written last, at ``index_pos``), so a bag cut short -- a robot that lost power,
a copy that stopped -- has none and rosbags refuses it whole. The bag format itself is simple and
self-delimiting, so the complete messages before the cut can be read in file order:

* a record is ``header_len (u32) | header | data_len (u32) | data``; the header is a list of
  ``field_len (u32) | name=value`` fields, ``op`` (one byte) naming the record type;
* bag header ``op=0x03`` (index_pos, conn_count, chunk_count; padded to 4 KiB), chunk ``op=0x05``
  (``compression`` none/bz2/lz4, ``size`` uncompressed; its data holds connection and message data
  records), connection ``op=0x07`` (``conn``, ``topic``; its data is a header with ``type``,
  ``md5sum``, ``message_definition``), message data ``op=0x02`` (``conn``, ``time`` as u32 sec +
  u32 nsec), index data ``op=0x04`` (``conn``, ``count`` messages of that connection in the chunk
  before), chunk info ``op=0x06`` (index section).

Damage: a chunk that does not decompress is dropped and its messages counted as lost per
connection from the index-data records that follow it; a record cut by the end of the file is
read as far as its bytes go (a cut chunk is decompressed in streaming mode and every complete
message in it kept). What could not be read is reported: bytes after the last complete record,
bytes the cut record declares beyond the end of the file, and the number of incomplete records.
"""

from __future__ import annotations

import bz2
import os
import struct
from dataclasses import dataclass, field
from typing import BinaryIO, Callable

import lz4.frame

BAG_MAGIC = b"#ROSBAG V2.0\n"
OP_MSG_DATA, OP_BAG_HEADER, OP_INDEX_DATA, OP_CHUNK, OP_CHUNK_INFO, OP_CONNECTION = 0x02, 0x03, 0x04, 0x05, 0x06, 0x07
_U32 = struct.Struct("<I")


class BagFormatError(ValueError):
    """A record header that is not a ROS 1 bag header (damage, not truncation)."""


@dataclass
class BagConnection:
    conn: int
    topic: str
    msgtype: str        # as written in the bag, e.g. ``sensor_msgs/Imu``
    md5sum: str
    msgdef: str


@dataclass
class BagScan:
    """What the scan read and what it could not."""

    size: int
    connections: dict[int, BagConnection] = field(default_factory=dict)
    messages: int = 0                  # complete message data records handed over
    recovered_from_cut: int = 0        # of which inside the record cut by the end of the file
    truncated: bool = False
    unread_bytes: int = 0              # bytes from the first incomplete record to the end of the file
    missing_bytes: int = 0             # bytes the cut record declares beyond the end of the file
    incomplete_records: int = 0        # records cut short (the top-level one, and one inside a cut chunk)
    corrupt_chunks: int = 0
    lost_per_conn: dict[int, int] = field(default_factory=dict)   # messages of dropped chunks
    unattributed: int = 0              # message records of a connection never defined
    warnings: list[str] = field(default_factory=list)


def _fields(header: bytes) -> dict[str, bytes]:
    """The ``field_len | name=value`` fields of a record header (or of a connection's data)."""
    out: dict[str, bytes] = {}
    p = 0
    while p < len(header):
        if p + 4 > len(header):
            raise BagFormatError("header field length runs past the header")
        (n,) = _U32.unpack_from(header, p)
        p += 4
        if p + n > len(header):
            raise BagFormatError("header field runs past the header")
        name, sep, value = header[p:p + n].partition(b"=")
        if not sep:
            raise BagFormatError("header field without '='")
        out[name.decode("ascii", "replace")] = value
        p += n
    return out


def header_fields(header: bytes) -> dict[str, bytes]:
    """The fields of a record header, which must name its one-byte ``op``."""
    out = _fields(header)
    if "op" not in out or len(out["op"]) != 1:
        raise BagFormatError("record header without a one-byte 'op'")
    return out


def _u32(fields: dict[str, bytes], name: str) -> int:
    return _U32.unpack(fields[name][:4])[0]


def _stamp_ns(raw: bytes) -> int:
    sec, nsec = struct.unpack("<II", raw[:8])
    return sec * 1_000_000_000 + nsec


def _connection(fields: dict[str, bytes], data: bytes) -> BagConnection:
    info = _fields(data)
    return BagConnection(_u32(fields, "conn"), fields.get("topic", info.get("topic", b"")).decode(),
                         info.get("type", b"").decode(), info.get("md5sum", b"").decode(),
                         info.get("message_definition", b"").decode())


def _decompress(compression: str, data: bytes, partial: bool) -> bytes:
    """A chunk's records; ``partial``: as much as a cut chunk's bytes give (never raises then)."""
    if compression == "none":
        return data
    if compression == "bz2":
        return bz2.BZ2Decompressor().decompress(data) if partial else bz2.decompress(data)
    if compression == "lz4":
        return lz4.frame.LZ4FrameDecompressor().decompress(data) if partial else lz4.frame.decompress(data)
    raise ValueError(f"unsupported chunk compression {compression!r}")


class _Reader:
    def __init__(self, path, on_message: Callable[[BagConnection, int, bytes], None],
                 progress: Callable[[int, int], None] | None):
        self.path, self.on_message, self.progress = path, on_message, progress
        self.scan = BagScan(size=os.path.getsize(path))
        self.after_bad_chunk = False
        self.pos = 0

    def record(self, fields: dict[str, bytes], data: bytes, in_cut: bool = False) -> None:
        """One record at top level or inside a chunk (chunks are handled by the caller)."""
        op = fields["op"][0]
        sc = self.scan
        if op == OP_CONNECTION:
            c = _connection(fields, data)
            sc.connections.setdefault(c.conn, c)
        elif op == OP_MSG_DATA:
            conn = sc.connections.get(_u32(fields, "conn"))
            if conn is None:
                sc.unattributed += 1
                return
            sc.messages += 1
            sc.recovered_from_cut += in_cut
            self.on_message(conn, _stamp_ns(fields["time"]), data)
        elif op == OP_INDEX_DATA and self.after_bad_chunk:
            cid = _u32(fields, "conn")
            sc.lost_per_conn[cid] = sc.lost_per_conn.get(cid, 0) + _u32(fields, "count")

    def chunk_records(self, buf: bytes, in_cut: bool) -> None:
        """Every record of a decompressed chunk; a record cut short ends the walk."""
        p, end = 0, len(buf)
        while p < end:
            if p + 4 > end:
                break
            (hl,) = _U32.unpack_from(buf, p)
            if p + 8 + hl > end:
                break
            fields = header_fields(buf[p + 4:p + 4 + hl])
            (dl,) = _U32.unpack_from(buf, p + 4 + hl)
            start = p + 8 + hl
            if start + dl > end:
                break
            self.record(fields, buf[start:start + dl], in_cut)
            p = start + dl
        if p < end:
            self.scan.incomplete_records += 1

    def cut(self, pos: int, declared_end: int | None) -> None:
        sc = self.scan
        sc.truncated = True
        sc.unread_bytes = sc.size - pos
        sc.missing_bytes = max(declared_end - sc.size, 0) if declared_end is not None else 0
        sc.incomplete_records += 1

    def run(self) -> BagScan:
        sc = self.scan
        with open(self.path, "rb") as f:
            if f.read(len(BAG_MAGIC)) != BAG_MAGIC:
                raise BagFormatError(f"{self.path}: not a ROS 1 bag v2.0 (bad magic)")
            self.pos = len(BAG_MAGIC)
            while self.pos < sc.size:
                end = self._top_record(f, self.pos)
                if end < 0:
                    break
                self.pos = end
                if self.progress is not None:
                    self.progress(end, sc.size)
        return sc

    def _top_record(self, f: BinaryIO, pos: int) -> int:
        """Read the record at ``pos``; its end, or -1 when the file ends inside it."""
        size = self.scan.size
        head = f.read(4)
        if len(head) < 4:
            self.cut(pos, None)
            return -1
        (hl,) = _U32.unpack(head)
        if pos + 4 + hl + 4 > size:
            self.cut(pos, pos + 4 + hl + 4)
            return -1
        fields = header_fields(f.read(hl))
        (dl,) = _U32.unpack(f.read(4))
        end = pos + 8 + hl + dl
        op = fields["op"][0]
        if end > size:   # the file ends inside this record's data
            self.cut(pos, end)
            if op == OP_CHUNK:
                try:
                    self.chunk_records(_decompress(fields["compression"].decode(), f.read(), partial=True),
                                       in_cut=True)
                except (BagFormatError, ValueError, KeyError, struct.error, OSError):
                    pass   # whatever decompressed before the damage is all there is
            return -1
        data = f.read(dl)
        if op == OP_CHUNK:
            try:
                buf = _decompress(fields["compression"].decode(), data, partial=False)
            except (ValueError, OSError, RuntimeError, EOFError, KeyError) as exc:
                self.scan.corrupt_chunks += 1
                self.scan.warnings.append(f"{self.path}: corrupt chunk at byte {pos} ({exc}); its messages "
                                          "are counted as lost, reading goes on")
                self.after_bad_chunk = True
                return end
            self.after_bad_chunk = False
            self.chunk_records(buf, in_cut=False)
        else:
            if op not in (OP_INDEX_DATA,):
                self.after_bad_chunk = False
            self.record(fields, data)
        return end


def scan_bag(path, on_message: Callable[[BagConnection, int, bytes], None],
             progress: Callable[[int, int], None] | None = None) -> BagScan:
    """Read every complete message of a ROS 1 bag front to back, without its index.

    Parameters
    ----------
    path : the ``.bag`` file (v2.0).
    on_message : ``(connection, log time ns, raw ROS 1 bytes)`` for each complete message, in file order.
    progress : optional ``(bytes_done, bytes_total)`` callback.

    Returns
    -------
    BagScan with the connections found, message counts and what was lost.

    Raises
    ------
    BagFormatError when the file is not a ROS 1 bag v2.0 or a record header is damaged beyond
    the last complete record (counts up to there are in the exception's ``scan`` attribute).
    """
    reader = _Reader(path, on_message, progress)
    try:
        return reader.run()
    except (BagFormatError, struct.error, KeyError, UnicodeDecodeError) as exc:
        if reader.scan.messages == 0:
            raise BagFormatError(f"{path}: not a readable ROS 1 bag ({exc})") from None
        sc = reader.scan
        sc.unread_bytes = sc.size - reader.pos
        sc.incomplete_records += 1
        sc.warnings.append(f"{path}: damaged record at byte {reader.pos} ({exc}); reading stopped there, "
                           f"{sc.unread_bytes} byte(s) after it unread, messages before kept")
        return sc
