"""Inspect a log without ingesting it: topics, types, counts, rates, time span, gaps, damage.

A gap is an interval between consecutive messages of a topic longer than two of that topic's
median periods. Every message of a type terrainml can decode is decoded, so corrupt messages are
counted; other types are only counted (``undecoded``).

Memory does not grow with the log (design §5): the readers hand each topic's log times over in
blocks and nothing decoded is kept; per topic only constant-size facts are held -- count, first and
last stamp, the largest interval, and a histogram of intervals at 1 µs resolution (its size is the
number of distinct periods, which jitter bounds, not the log length) from which the median period
and the gaps are taken. A topic whose stamps are out of order in the file is read once more and its
stamps sorted (8 bytes per message of that topic: damaged logs only), as before.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from terrainml.io import cdr
from terrainml.io.readers import LogReadError, ReadResult, is_rosbag2, log_size, read_bag, read_mcap, sniff_format

_US = 1000   # histogram resolution of intervals, ns


@dataclass
class _Stamps:
    """Constant-size facts of one topic's log times in file order."""

    n: int = 0
    last: int | None = None
    out_of_order: int = 0
    max_dt_ns: int = 0
    hist: Counter = field(default_factory=Counter)   # interval (µs) -> count, intervals >= 0 only

    def add(self, t: np.ndarray) -> None:
        if not len(t):
            return
        dt = np.diff(t, prepend=t[0] if self.last is None else self.last)
        if self.last is None:
            dt = dt[1:]
        self.n += len(t)
        self.last = int(t[-1])
        back = dt < 0
        self.out_of_order += int(np.count_nonzero(back))
        fwd = dt[~back]
        if len(fwd):
            self.max_dt_ns = max(self.max_dt_ns, int(fwd.max()))
            us, cnt = np.unique(np.rint(fwd / _US).astype(np.int64), return_counts=True)
            self.hist.update(dict(zip(us.tolist(), cnt.tolist())))

    def median_s(self) -> float:
        """Median interval (s, to 1 µs) of the intervals counted."""
        keys = sorted(self.hist)
        counts = np.cumsum([self.hist[k] for k in keys])
        m = int(counts[-1])

        def kth(r: int) -> int:   # r-th smallest interval (0-based), µs
            return keys[int(np.searchsorted(counts, r + 1))]

        med = kth(m // 2) if m % 2 else 0.5 * (kth(m // 2 - 1) + kth(m // 2))
        return med * _US * 1e-9

    def gaps(self, med_s: float) -> int:
        return sum(c for k, c in self.hist.items() if k * _US * 1e-9 > 2.0 * med_s)


def _timing(d: dict[str, Any], n: int, span_s: float, med_s: float, gaps: int, max_gap_s: float) -> None:
    if n >= 2:
        d["span_s"] = span_s
        d["rate_hz"] = (n - 1) / span_s if span_s > 0 else None
        d["gaps"] = gaps if med_s > 0 else 0
        d["max_gap_s"] = max_gap_s


def _read(path: Path, fmt: str, wanted, on_times) -> ReadResult:
    def drop(topic: str, part: dict) -> None:   # decoded only to count corrupt messages
        pass

    if fmt == "mcap":
        return read_mcap(path, wanted, on_times=on_times, on_part=drop)
    return read_bag(path, wanted, on_times=on_times, on_part=drop)


def inspect_log(path: str | Path) -> dict[str, Any]:
    """Summary of a ``.mcap`` or ``.bag`` log, or a ROS 2 bag folder (``.db3`` or MCAP), as a JSON-ready dict.

    Raises
    ------
    LogReadError if the file is not a log at all.
    """
    path = Path(path)
    if not path.exists():
        raise LogReadError(f"{path}: file not found")
    if path.is_dir() and is_rosbag2(path) and len(list(path.glob("*.mcap"))) == 1:
        path = next(path.glob("*.mcap"))   # a bag folder with one MCAP file: our MCAP reader
    fmt = sniff_format(path)
    if fmt not in ("mcap", "bag", "rosbag2"):
        raise LogReadError(f"{path}: inspect reads ROS logs (.mcap, .bag, ROS 2 bag folders); this is {fmt} "
                           "(use `terrainml ingest` for tables)")
    stamps: dict[str, _Stamps] = {}

    def on_times(topic: str, t: np.ndarray) -> None:
        stamps.setdefault(topic, _Stamps()).add(t)

    res = _read(path, fmt, lambda topic, type_name: cdr.KIND_OF_TYPE.get(type_name), on_times)
    disorder = {topic for topic, s in stamps.items() if s.out_of_order}
    held: dict[str, list] = {}
    if disorder:   # exact figures for out-of-order topics: their stamps, sorted
        _read(path, fmt, lambda topic, type_name: None,
              lambda topic, t: held.setdefault(topic, []).append(t) if topic in disorder else None)
    topics: dict[str, Any] = {}
    t_first = min((s.first_ns for s in res.stats.values() if s.first_ns is not None), default=None)
    t_last = max((s.last_ns for s in res.stats.values() if s.last_ns is not None), default=None)
    for topic, st in sorted(res.stats.items()):
        s = stamps.get(topic, _Stamps())
        d: dict[str, Any] = {"type": st.type, "count": st.read, "corrupt": st.corrupt,
                             "undecoded": st.read - st.decoded - st.corrupt if res.kinds.get(topic) == "" else 0,
                             "rate_hz": None, "span_s": 0.0, "gaps": 0, "max_gap_s": None,
                             "out_of_order": s.out_of_order}
        if topic in held:
            tn = np.sort(np.concatenate(held.pop(topic)))
            dt = np.diff(tn) * 1e-9
            med = float(np.median(dt)) if len(dt) else 0.0
            _timing(d, len(tn), float(tn[-1] - tn[0]) * 1e-9, med,
                    int(np.count_nonzero(dt > 2.0 * med)), float(dt.max()) if len(dt) else 0.0)
        elif s.n >= 2:
            med = s.median_s()
            _timing(d, s.n, (st.last_ns - st.first_ns) * 1e-9, med, s.gaps(med), s.max_dt_ns * 1e-9)
        topics[topic] = d
    return {
        "file": str(path), "format": fmt, "size_bytes": log_size(path),
        "start_ns": t_first, "end_ns": t_last,
        "span_s": (t_last - t_first) * 1e-9 if t_first is not None else 0.0,
        "messages": sum(s.read for s in res.stats.values()),
        "corrupt": sum(s.corrupt for s in res.stats.values()) + res.unattributed_corrupt,
        "corrupt_chunks": res.corrupt_chunks, "truncated": res.truncated,
        "truncation": res.truncation(),
        "topics": topics, "warnings": res.warnings,
    }
