"""ROS 1 bag and ROS 2 bag folder readers (``.db3`` or MCAP storage), message by message,
damage-tolerant: the intact messages of a cut or damaged bag are kept and the lost ones counted."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import yaml
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Reader as Rosbag2Reader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.msg import normalize_msgtype

from terrainml.io import cdr, ros1bag
from terrainml.io.read_result import LogReadError, OnTimes, ReadResult, truncation_warning
from terrainml.io.rosbag2db import Db3Error, Db3File, open_db3

__all__ = ["read_bag"]

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
        res.warnings.append(truncation_warning(path, res))
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
