"""What a log reader reports: per-topic counts, decoded parts, warnings and damage."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

__all__ = ["LogReadError", "TopicStats", "ReadResult", "OnTimes", "truncation_warning"]

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



def truncation_warning(path: Path, res: ReadResult) -> str:
    """The warning for a truncated log: what was lost, what was kept."""
    lost = f"{res.unread_bytes:,} byte(s) at the end unread" if res.unread_bytes else "no summary/footer"
    if res.missing_bytes:
        lost += f", {res.missing_bytes:,} byte(s) of the last record missing"
    if res.incomplete_records:
        lost += f", {res.incomplete_records} incomplete record(s)"
    return (f"{path}: file is truncated ({lost}); every complete message before the cut was kept"
            + (f" ({res.recovered_from_cut} from inside the cut record)" if res.recovered_from_cut else ""))
