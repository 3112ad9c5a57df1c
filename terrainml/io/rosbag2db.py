"""Damage-tolerant reading of a ROS 2 bag's SQLite storage (``.db3``), row by row.

Why this is hand-written rather than left to rosbags: SQLite refuses a damaged database as a
whole. A truncated file fails at open ("database disk image is malformed": the header declares
more pages than the file holds), and one bad page fails every query whose scan reaches it, so
rosbags' reader -- which counts each topic's messages in one scan of the ``messages`` table when
it opens the bag -- refuses the whole bag for a single bad page. Reading the table row by row in
rowid order instead lets the intact pages through:

* the connection turns ``writable_schema`` on (read-only still), so SQLite takes the file's size
  over the header's page count and a truncated file opens;
* rows are read with one cursor in rowid order; when a row does not read (its page is damaged or
  past the end of the file), the reader reads on one row at a time and seeks past it by rowid --
  a B-tree seek touches only the pages on the path to one row -- one id at a time first, then in
  doubling steps (a damaged interior page hides a whole range of ids), and goes on from the next
  row that reads;
* what was lost is counted: rows whose key was found but whose content did not read, and the
  number of unreadable rowid ranges. Per-topic losses are the caller's (the bag's
  ``metadata.yaml`` says how many messages each topic had).

Only a file whose ``topics`` table cannot be read is refused (:class:`Db3Error`).
"""

from __future__ import annotations

import sqlite3
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

__all__ = ["Db3Error", "Db3File", "open_db3"]

_MAX_ID = 2**63 - 1
_LINEAR_PROBES = 64        # ids tried one by one past a damaged row before the steps double
_SINGLE = 64               # rows read one at a time past damage before the cursor resumes
_ROWS = "SELECT id, topic_id, timestamp, data FROM messages"


class Db3Error(ValueError):
    """The storage file cannot be read at all (not even its topics); the message names the file."""


@dataclass
class Db3File:
    """One open ``.db3`` storage file, its topics and what reading its rows lost.

    Attributes
    ----------
    topics : topic id -> (topic name, message type).
    msgdefs : message type -> its ``ros2msg`` definition text (schema 4 and later; may be empty).
    lost_rows : rows whose id was found but whose content did not read.
    bad_ranges : unreadable rowid ranges skipped (a damaged page or run of pages each).
    page_size, declared_bytes, file_bytes : the header's page size and database size (0 when the
        header does not say) and the file's size; ``declared_bytes > file_bytes``: truncated.
    """

    path: Path
    conn: sqlite3.Connection
    topics: dict[int, tuple[str, str]] = field(default_factory=dict)
    msgdefs: dict[str, str] = field(default_factory=dict)
    lost_rows: int = 0
    bad_ranges: int = 0
    page_size: int = 0
    declared_bytes: int = 0
    file_bytes: int = 0

    @property
    def truncated(self) -> bool:
        return self.declared_bytes > self.file_bytes

    def close(self) -> None:
        self.conn.close()

    def rows(self) -> Iterator[tuple[int, int, int, bytes]]:
        """Every readable row ``(id, topic_id, timestamp_ns, data)`` in rowid order; rows that do not
        read are skipped and counted (``lost_rows``, ``bad_ranges``).

        One cursor while the pages read; where it hits damage (Python's cursor steps one row
        ahead, so the error can come with the last good row), one row at a time until
        ``_SINGLE`` rows in a row have read, then the cursor again."""
        last = 0
        while True:
            try:
                for row in self.conn.execute(_ROWS + " WHERE id > ? ORDER BY id", (last,)):
                    last = row[0]
                    yield row
                return
            except sqlite3.DatabaseError:
                pass
            good = 0
            while good < _SINGLE:
                row, skipped = self._next_row(last)
                self.bad_ranges += int(skipped)
                if row is None:
                    return
                last, good = row[0], 0 if skipped else good + 1
                yield row

    def _next_row(self, after: int) -> tuple[tuple | None, bool]:
        """The next row after ``after`` that reads, read alone (None: none), and whether rows or
        ids were skipped on the way; rows found by id but unreadable are counted one by one."""
        p, skipped = after + 1, False
        while True:
            key, failed = self._next_key(p)
            skipped |= failed
            if key is None:
                return None, skipped
            try:
                row = self.conn.execute(_ROWS + " WHERE id = ?", (key,)).fetchone()
            except sqlite3.DatabaseError:
                row = None
            if row is not None:
                return row, skipped
            self.lost_rows += 1
            skipped, p = True, key + 1

    def _seek(self, p: int) -> tuple[bool, int | None]:
        """(readable, first id >= p) by a key-only B-tree seek; (False, None) where it hits damage."""
        try:
            row = self.conn.execute("SELECT id FROM messages WHERE id >= ? ORDER BY id LIMIT 1", (p,)).fetchone()
        except sqlite3.DatabaseError:
            return False, None
        return True, None if row is None else int(row[0])

    def _next_key(self, p: int) -> tuple[int | None, bool]:
        """The first id >= ``p`` a seek reaches (None: no id after ``p``) and whether seeks failed
        on the way: ids one by one, then doubling steps past the damage, then a bisection back to
        the first id that seeks."""
        start = p
        bad, step, probes = p - 1, 1, 0
        while p <= _MAX_ID:
            ok, key = self._seek(p)
            if ok:
                break
            bad, probes = p, probes + 1
            step = step * 2 if probes > _LINEAR_PROBES else 1
            p = min(p + step, _MAX_ID) if p < _MAX_ID else _MAX_ID + 1
        else:
            return None, True
        lo, hi = bad, p                     # lo does not seek, hi does
        while hi - lo > 1:
            mid = (lo + hi) // 2
            if self._seek(mid)[0]:
                hi = mid
            else:
                lo = mid
        return (self._seek(hi)[1] if hi != p else key), bad >= start


def _header_sizes(path: Path) -> tuple[int, int]:
    """(page size, database bytes the header declares; 0 when its page count is not valid)."""
    with open(path, "rb") as f:
        head = f.read(100)
    if len(head) < 100 or not head.startswith(b"SQLite format 3\x00"):
        return 0, 0
    page = struct.unpack(">H", head[16:18])[0]
    page = 65536 if page == 1 else page
    change, n_pages, valid_for = (struct.unpack(">I", head[k:k + 4])[0] for k in (24, 28, 92))
    return page, (n_pages * page if n_pages and change == valid_for else 0)


def _read_topics(conn: sqlite3.Connection) -> tuple[dict[int, tuple[str, str]], dict[str, str]]:
    """Topics (id -> name, type) and, where the schema has them, message definitions by type."""
    topics = {int(i): (str(n), str(t)) for i, n, t in conn.execute("SELECT id, name, type FROM topics")}
    msgdefs: dict[str, str] = {}
    try:
        for typ, enc, text in conn.execute(
                "SELECT topic_type, encoding, encoded_message_definition FROM message_definitions"):
            if enc == "ros2msg" and text:
                msgdefs[str(typ)] = str(text)
    except sqlite3.DatabaseError:    # no such table (schema < 4) or a damaged page: types from the store
        pass
    return topics, msgdefs


def open_db3(path: Path) -> Db3File:
    """Open a ``.db3`` storage file read-only, damaged or not, and read its topics.

    Parameters
    ----------
    path : the storage file (inside a ROS 2 bag folder).

    Returns
    -------
    Db3File; iterate ``rows()`` for its messages.

    Raises
    ------
    Db3Error : the file is not an SQLite database or its ``topics`` table cannot be read.
    """
    path = Path(path)
    try:
        page, declared = _header_sizes(path)
        size = path.stat().st_size
        conn = sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro&immutable=1", uri=True)
    except (OSError, sqlite3.Error) as exc:
        raise Db3Error(f"{path}: cannot open the ROS 2 bag storage file ({exc})") from None
    try:
        conn.execute("PRAGMA writable_schema=ON")   # trust the file's size over the header's (truncated)
        topics, msgdefs = _read_topics(conn)
    except sqlite3.DatabaseError as exc:
        conn.close()
        raise Db3Error(f"{path}: not a readable ROS 2 bag storage file, not even its topics table "
                       f"({exc})") from None
    return Db3File(path, conn, topics, msgdefs, page_size=page, declared_bytes=declared, file_bytes=size)
