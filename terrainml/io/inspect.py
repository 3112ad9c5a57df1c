"""Inspect a log without ingesting it: topics, types, counts, rates, time span, gaps, damage.

A gap is an interval between consecutive messages of a topic longer than two of that topic's
median periods. Every message of a type terrainml can decode is decoded, so corrupt messages are
counted; other types are only counted (``undecoded``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from terrainml.io import cdr
from terrainml.io.readers import LogReadError, read_bag, read_mcap, sniff_format


def inspect_log(path: str | Path) -> dict[str, Any]:
    """Summary of a ``.mcap`` or ``.bag`` log as a JSON-ready dict.

    Raises
    ------
    LogReadError if the file is not a log at all.
    """
    path = Path(path)
    if not path.is_file():
        raise LogReadError(f"{path}: file not found")
    fmt = sniff_format(path)
    if fmt not in ("mcap", "bag"):
        raise LogReadError(f"{path}: inspect reads ROS logs (.mcap, .bag); this is {fmt} "
                           "(use `terrainml ingest` for tables)")

    def wanted(topic: str, type_name: str) -> str | None:
        return cdr.KIND_OF_TYPE.get(type_name)

    res = read_mcap(path, wanted, keep_times=True) if fmt == "mcap" else read_bag(path, wanted, keep_times=True)
    topics: dict[str, Any] = {}
    t_first = min((s.first_ns for s in res.stats.values() if s.first_ns is not None), default=None)
    t_last = max((s.last_ns for s in res.stats.values() if s.last_ns is not None), default=None)
    for topic, st in sorted(res.stats.items()):
        tn = np.sort(np.asarray(st.times or [], np.int64))
        t = (tn - tn[0]) * 1e-9 if len(tn) else tn * 1e-9
        d: dict[str, Any] = {"type": st.type, "count": st.read, "corrupt": st.corrupt,
                             "undecoded": st.read - st.decoded - st.corrupt if res.kinds.get(topic) == "" else 0,
                             "rate_hz": None, "span_s": 0.0, "gaps": 0, "max_gap_s": None,
                             "out_of_order": int(np.count_nonzero(np.diff(np.asarray(st.times or [])) < 0))}
        if len(t) >= 2:
            dt = np.diff(t)
            span = float(t[-1] - t[0])
            d["span_s"] = span
            d["rate_hz"] = (len(t) - 1) / span if span > 0 else None
            med = float(np.median(dt))
            d["gaps"] = int(np.count_nonzero(dt > 2.0 * med)) if med > 0 else 0
            d["max_gap_s"] = float(dt.max())
        topics[topic] = d
    return {
        "file": str(path), "format": fmt, "size_bytes": path.stat().st_size,
        "start_ns": t_first, "end_ns": t_last,
        "span_s": (t_last - t_first) * 1e-9 if t_first is not None else 0.0,
        "messages": sum(s.read for s in res.stats.values()),
        "corrupt": sum(s.corrupt for s in res.stats.values()) + res.unattributed_corrupt,
        "corrupt_chunks": res.corrupt_chunks, "truncated": res.truncated,
        "topics": topics, "warnings": res.warnings,
    }
