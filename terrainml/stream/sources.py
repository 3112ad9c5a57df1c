"""Where base-rate samples come from: a log file, UDP JSON datagrams, stdin JSON lines (SYSTEM §11).

A *sample* is a dict with ``t_s`` and canonical run-table column names (SYSTEM §5), e.g.
``{"t_s": 1.23, "wheel1_omega_radps": 6.1, ..., "imu_ax_mps2": 0.02, ...}``; missing groups,
``null`` or non-finite values simply make that sensor group invalid for the tick.

Source specs (``terrainml predict --source``)::

    RUN.mcap | RUN.bag | RUN.parquet | RUN.csv   a recorded log (as fast as possible, or --realtime)
    udp://HOST:PORT                              one JSON object per datagram (default 127.0.0.1:9870)
    -                                            JSON lines on stdin

Log files are read through the io owner's ingest (:func:`terrainml.io.ingest.load_run`), i.e. the
very same topic decoding, frame mapping and resampling to the base rate as training used.
Malformed datagrams / lines (not JSON, not an object, no finite ``t_s``) are counted in
:class:`SourceCounters` and skipped. A datagram or line ``{"eos": true}`` ends the stream.
"""

from __future__ import annotations

import json
import logging
import math
import socket
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, Iterator

log = logging.getLogger("terrainml.stream")

DEFAULT_UDP_SOURCE = ("127.0.0.1", 9870)


class SourceError(ValueError):
    """A source spec cannot be opened (the message names the file or address)."""


@dataclass
class SourceCounters:
    received: int = 0
    malformed: int = 0

    def as_dict(self) -> dict[str, int]:
        return {"received": self.received, "malformed": self.malformed}


_EOS = object()


def parse_sample(data: bytes | str, counters: SourceCounters | None = None) -> Any:
    """Parse one datagram or line into a sample dict; None if malformed (counted); _EOS at end."""
    if counters is not None:
        counters.received += 1
    try:
        obj = json.loads(data)
    except (ValueError, UnicodeDecodeError):
        obj = None
    if isinstance(obj, dict) and obj.get("eos") is True:
        return _EOS
    ok = isinstance(obj, dict) and "t_s" in obj
    if ok:
        t = obj["t_s"]
        ok = isinstance(t, (int, float)) and not isinstance(t, bool) and math.isfinite(t)
    if not ok:
        if counters is not None:
            counters.malformed += 1
            if counters.malformed <= 3:
                log.warning("malformed sample skipped (%d so far): %.80r", counters.malformed, data)
        return None
    return obj


# --------------------------------------------------------------------------- log files
def iter_log_samples(path: str | Path, robot: Any = None, *, rate_hz: float = 100.0,
                     realtime: bool = False, topic_map: Any = None) -> Iterator[dict]:
    """Samples of a recorded log at the base rate (ingest + resampling of the io owner).

    With ``realtime`` each sample is released at its ``t_s`` relative to the start (wall clock).
    """
    path = Path(path)
    if not path.is_file():
        raise SourceError(f"{path}: file not found")
    from terrainml.io.ingest import load_run

    try:
        res = load_run(path, robot=robot, topic_map=topic_map, rate_hz=rate_hz)
    except Exception as exc:  # noqa: BLE001 - ingest raises named errors; report them cleanly
        raise SourceError(f"{path}: cannot read log ({exc})") from None
    report = getattr(res, "report", None)
    if report is not None and getattr(report, "usable", True) is False:
        raise SourceError(f"{path}: log is not usable ({getattr(report, 'warnings', '')})")
    yield from iter_table_samples(res.table, realtime=realtime)


def iter_table_samples(table: Any, *, realtime: bool = False) -> Iterator[dict]:
    """Rows of a run table (DataFrame) as sample dicts, optionally paced at their ``t_s``."""
    cols = [str(c) for c in table.columns]
    t0_wall = None
    t0 = None
    for values in table.itertuples(index=False, name=None):
        sample = {}
        for c, v in zip(cols, values):
            if hasattr(v, "item"):
                v = v.item()
            sample[c] = v
        if realtime:
            t = float(sample["t_s"])
            if t0_wall is None:
                t0_wall, t0 = time.perf_counter(), t
            delay = (t - t0) - (time.perf_counter() - t0_wall)
            if delay > 0:
                time.sleep(delay)
        yield sample


# --------------------------------------------------------------------------- udp / stdin
def bind_udp(host: str, port: int) -> socket.socket:
    """A UDP socket bound to ``host:port`` with a large receive buffer; raises SourceError."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 * 2**20)
    except OSError:
        pass
    try:
        sock.bind((host, int(port)))
    except OSError as exc:
        sock.close()
        raise SourceError(f"udp://{host}:{port}: cannot bind ({exc})") from None
    return sock


def iter_udp_samples(host: str = DEFAULT_UDP_SOURCE[0], port: int = DEFAULT_UDP_SOURCE[1], *,
                     counters: SourceCounters | None = None, idle_timeout_s: float | None = None,
                     sock: socket.socket | None = None, ready: Any = None) -> Iterator[dict]:
    """Samples from JSON datagrams on ``host:port`` until ``{"eos": true}`` or ``idle_timeout_s``."""
    counters = counters if counters is not None else SourceCounters()
    if sock is None:
        sock = bind_udp(host, port)
    sock.settimeout(idle_timeout_s if idle_timeout_s else None)
    if ready is not None:
        ready(sock.getsockname())
    try:
        while True:
            try:
                data, _ = sock.recvfrom(65535)
            except socket.timeout:
                log.info("udp source idle for %.1f s: end of stream", idle_timeout_s)
                return
            s = parse_sample(data, counters)
            if s is _EOS:
                return
            if s is not None:
                yield s
    finally:
        sock.close()


def iter_line_samples(stream: IO[str] | None = None, *,
                      counters: SourceCounters | None = None) -> Iterator[dict]:
    """Samples from JSON lines (default stdin); blank lines are ignored."""
    counters = counters if counters is not None else SourceCounters()
    stream = stream or sys.stdin
    for line in stream:
        if not line.strip():
            continue
        s = parse_sample(line, counters)
        if s is _EOS:
            return
        if s is not None:
            yield s


def open_source(spec: str, *, robot: Any = None, realtime: bool = False,
                counters: SourceCounters | None = None, idle_timeout_s: float | None = None,
                rate_hz: float = 100.0, ready: Any = None) -> Iterator[dict]:
    """Iterator of samples for a ``--source`` spec (see the module docstring)."""
    s = spec.strip()
    if s == "-":
        if ready is not None:
            ready(None)
        return iter_line_samples(counters=counters)
    if s.startswith("udp://") or s == "udp":
        rest = s[len("udp://"):] if s != "udp" else ""
        host, port = DEFAULT_UDP_SOURCE
        if rest:
            h, _, p = rest.rpartition(":")
            try:
                host, port = (h or host), int(p)
            except ValueError:
                raise SourceError(f"source {spec!r}: expected udp://HOST:PORT") from None
        sock = bind_udp(host, port)
        return iter_udp_samples(host, port, counters=counters, idle_timeout_s=idle_timeout_s,
                                sock=sock, ready=ready)
    path = Path(s)
    if not path.is_file():
        raise SourceError(f"source {spec!r}: no such file (expected RUN.mcap, udp://HOST:PORT or -)")
    if ready is not None:
        ready(None)
    return iter_log_samples(path, robot, rate_hz=rate_hz, realtime=realtime)
