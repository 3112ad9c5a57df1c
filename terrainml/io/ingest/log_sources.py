"""The logs the ingest engine reads: a decoded part (:mod:`terrainml.io.cdr`) at a time, in file order.

:class:`FileLog` re-reads the file for every pass (bounded memory), :class:`MemoryLog` reads it once
and replays the parts.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

from terrainml.io import cdr
from terrainml.io.readers import ReadResult, log_size, read_bag, read_mcap
from terrainml.io.topicmap import TopicMap

__all__ = ["OnPart", "FileLog", "MemoryLog"]

OnPart = Callable[[str, dict], None]


def _wanted_for(tmap: TopicMap, topics: set[str] | None = None):
    """The reader's ``wanted(topic, type) -> decode kind`` for a topic map (only ``topics`` when
    given), and the dict it fills with mapped topics whose type does not match."""
    by_topic = tmap.by_topic()
    mismatched: dict[str, str] = {}

    def wanted(topic: str, type_name: str) -> str | None:
        src = by_topic.get(topic)
        if src is None or (topics is not None and topic not in topics):
            return None
        if (src.type and type_name != src.type) or cdr.KIND_OF_TYPE.get(type_name) != src.decode_kind:
            mismatched[topic] = type_name
            return None
        return src.decode_kind

    return wanted, mismatched


class FileLog:
    """A log re-read from disk on every pass: memory bounded by one MCAP chunk (``ingest --out``)."""

    kept = False   # decoded parts are not held between passes

    def __init__(self, path: Path, fmt: str, tmap: TopicMap, progress=None, passes: int = 2):
        self.path, self.fmt, self.tmap, self.progress = path, fmt, tmap, progress
        self.size = max(log_size(path), 1)
        self.passes, self.done = passes, 0
        self.validate_crcs = True
        self.mismatched: dict[str, str] = {}

    def release(self) -> None:
        """Nothing is kept between passes."""

    def read(self, on_part: OnPart, topics: set[str] | None = None) -> ReadResult:
        """One pass over the file (only ``topics`` decoded when given); progress spans all passes."""
        wanted, mismatched = _wanted_for(self.tmap, topics)
        offset = min(self.done, self.passes - 1) * self.size
        prog = None if self.progress is None else \
            (lambda done, total: self.progress(offset + done, self.passes * self.size))
        hdr = self.tmap.stamp == "header"
        if self.fmt == "mcap":
            res = read_mcap(self.path, wanted, use_header_stamp=hdr, progress=prog, on_part=on_part,
                            validate_crcs=self.validate_crcs)
        else:
            res = read_bag(self.path, wanted, use_header_stamp=hdr, progress=prog, on_part=on_part)
        if topics is None:
            self.done += 1
            if self.done == 1:
                self.mismatched = mismatched
                # every chunk passed its CRC in the first pass: later reads skip the check (same bytes)
                self.validate_crcs = res.corrupt_chunks > 0
        return res


class MemoryLog(FileLog):
    """A log read once, its decoded parts kept and replayed by later passes (``load_run``)."""

    kept = True

    def __init__(self, path: Path, fmt: str, tmap: TopicMap, progress=None):
        super().__init__(path, fmt, tmap, progress, passes=1)
        self.parts: list[tuple[str, dict]] | None = None

    def read(self, on_part: OnPart, topics: set[str] | None = None) -> ReadResult | None:
        if self.parts is None:
            self.parts = []
            return super().read(lambda topic, p: (self.parts.append((topic, p)), on_part(topic, p)))
        for topic, p in self.parts:
            if topics is None or topic in topics:
                on_part(topic, p)
        return None

    def release(self) -> None:
        self.parts = []
