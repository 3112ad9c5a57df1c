"""Streaming, damage-tolerant log readers: ROS 2 MCAP and ROS 1 bag, and the log format test.

Both yield the same thing: per topic, decoded numeric parts (see :mod:`terrainml.io.cdr`) plus
per-topic counts of messages read, corrupt and skipped, so ingest and inspect share one pass.

The MCAP reader is :mod:`terrainml.io.mcap_reader`, the bag readers :mod:`terrainml.io.bag_reader`,
their report :mod:`terrainml.io.read_result`; this module tells the formats apart and gives the
readers one import path. Messages are not sorted here; ingest sorts per topic and counts
out-of-order/duplicate stamps.
"""

from __future__ import annotations

import os
from pathlib import Path

from terrainml.io.bag_reader import read_bag as read_bag
from terrainml.io.mcap_reader import MCAP_MAGIC, McapScanner as McapScanner, read_mcap as read_mcap
from terrainml.io.read_result import (LogReadError, OnTimes as OnTimes, ReadResult as ReadResult,
                                      TopicStats as TopicStats)

__all__ = ["LogReadError", "TopicStats", "ReadResult", "OnTimes", "MCAP_MAGIC", "BAG_MAGIC", "McapScanner",
           "read_mcap", "read_bag", "is_rosbag2", "log_size", "sniff_format"]

BAG_MAGIC = b"#ROSBAG V2.0"


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
