"""``inspect`` memory does not grow with the log's length (it was 67 MiB at 1 minute and
320 MiB at 30 minutes, every stamp and decoded message kept).

The peak of Python allocations (tracemalloc, which numpy reports to) while inspecting a 10-s and a
60-s log must stay within 10 % plus 64 KiB: keeping even one float per message would add 120 KiB,
keeping the decoded messages several MiB. The end-to-end figure (peak RSS, 1 vs 30 minutes) is
``benchmarks/bench_inspect.py``.
"""

from __future__ import annotations

import tracemalloc

import numpy as np

from terrainml.io.inspect import inspect_log
from terrainml.io.mcap_writer import RosMcapWriter


def _write_log(path, seconds: float) -> int:
    """IMU, wheel joints and motor currents at 100 Hz; returns the message count (ground truth)."""
    n = int(seconds * 100)
    # 64 KiB chunks: both logs span many chunks, so the chunk buffer is the same size in both
    with RosMcapWriter(path, 3, chunk_size=64 * 1024) as w:
        for t in np.arange(n) / 100.0:
            w.write_imu(float(t), (0.01, 0.0, 9.81), (0.0, 0.0, 0.1))
            w.write_wheel_joints(float(t), [6.0] * 3, [0.0] * 3)
            w.write_motor_current(float(t), [2.0] * 3)
    return 3 * n


def _peak_bytes(path) -> tuple[int, int]:
    tracemalloc.start()
    try:
        info = inspect_log(path)
        return tracemalloc.get_traced_memory()[1], info["messages"]
    finally:
        tracemalloc.stop()


def test_inspect_peak_memory_is_flat_in_log_length(tmp_path):
    short, long_ = tmp_path / "short.mcap", tmp_path / "long.mcap"
    n_short, n_long = _write_log(short, 10.0), _write_log(long_, 60.0)
    _peak_bytes(short)  # first call: imports and caches, not the log
    peak_short, msgs_short = _peak_bytes(short)
    peak_long, msgs_long = _peak_bytes(long_)
    assert (msgs_short, msgs_long) == (n_short, n_long)
    assert peak_long <= 1.10 * peak_short + 64 * 1024, (peak_short, peak_long)
