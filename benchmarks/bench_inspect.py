"""Inspect benchmark: ``terrainml inspect`` peak RSS must not grow with the log's length.

Logs: the 5-topic ROS 2 MCAP of :mod:`benchmarks.bench_ingest` (T265 200 Hz, IMU, wheel joints,
motor currents 100 Hz, cmd_vel 20 Hz), 1 minute and 30 minutes long. Each ``inspect_log`` runs in
a fresh subprocess and reports its own peak resident memory (VmHWM, as bench_ingest). Goal: the
30-minute figure at most 10 % above the 1-minute one (it was 67 -> 320 MiB when every stamp and
every decoded message was kept).

Run: ``.venv/bin/python -m benchmarks.run_all --only bench_inspect --out /tmp/b.md``
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.bench_ingest import _PEAK, _machine, write_log

_SNIPPETS = {
    "imports": _PEAK + "import sys\nimport terrainml.io.inspect\nprint(peak())\n",
    "inspect": _PEAK + ("import sys, time\nimport terrainml.io.inspect\nt0 = time.perf_counter()\n"
                        "info = terrainml.io.inspect.inspect_log(sys.argv[1])\n"
                        "dt = time.perf_counter() - t0\nassert info['messages'] > 0\n"
                        "print(info['messages'], dt)\nprint(peak())\n"),
}


def peak_rss(mode: str, path: Path | None = None) -> tuple[float, int, float]:
    """(peak RSS MiB, messages, seconds) of a fresh process running ``mode``."""
    cmd = [sys.executable, "-c", _SNIPPETS[mode]] + ([str(path)] if path is not None else [])
    res = subprocess.run(cmd, capture_output=True, text=True)
    if res.returncode:
        raise RuntimeError(f"peak RSS child ({mode}) failed: {res.stderr[-2000:]}")
    lines = res.stdout.strip().splitlines()
    msgs, secs = (int(lines[0].split()[0]), float(lines[0].split()[1])) if mode == "inspect" else (0, 0.0)
    return int(lines[-1]) / 1024.0, msgs, secs


def run(quick: bool = False) -> str:
    short_s, long_s = (6.0, 180.0) if quick else (60.0, 1800.0)
    with tempfile.TemporaryDirectory() as tmp:
        short_log, long_log = Path(tmp) / "short.mcap", Path(tmp) / "long.mcap"
        t0 = time.perf_counter()
        write_log(short_log, short_s)
        write_log(long_log, long_s)
        t_write = time.perf_counter() - t0
        size = {k: p.stat().st_size / 2**20 for k, p in (("short", short_log), ("long", long_log))}
        base, _, _ = peak_rss("imports")
        short = peak_rss("inspect", short_log)
        long = peak_rss("inspect", long_log)
    growth = long[0] / short[0] - 1.0
    sm, lm = f"{short_s / 60:g}", f"{long_s / 60:g}"
    return "\n".join([
        "## Inspect (peak memory vs log length)",
        "",
        f"Machine: {_machine()}. Logs: the bench_ingest 5-topic ROS 2 MCAP (T265 200 Hz, IMU, wheel "
        f"joints, motor currents 100 Hz, cmd_vel 20 Hz), {sm} and {lm} min (written in {t_write:.0f} s). "
        "Each `inspect_log` in a fresh process; peak RSS is the child's VmHWM.",
        "",
        f"| | {sm}-min log | {lm}-min log | growth |",
        "|---|---:|---:|---:|",
        f"| log size, MiB | {size['short']:.1f} | {size['long']:.1f} | |",
        f"| messages | {short[1]:,} | {long[1]:,} | |",
        f"| inspect time, s | {short[2]:.2f} | {long[2]:.2f} | |",
        f"| imports only (terrainml.io.inspect), MiB | {base:.0f} | {base:.0f} | |",
        f"| `terrainml inspect` peak RSS, MiB | {short[0]:.0f} | {long[0]:.0f} | **{growth:+.1%}** |",
        "",
        f"Peak RSS from the {sm}-min to the {lm}-min log: {growth:+.1%} (goal: <= +10 %, "
        f"{'met' if growth <= 0.10 else 'NOT met'}). Inspect keeps per topic a count, first/last stamp, "
        "the largest interval and a histogram of intervals at 1 µs (bounded by the jitter, not the "
        "length); the reader hands stamps over in blocks and keeps no decoded message.",
        "",
    ])


if __name__ == "__main__":  # pragma: no cover
    print(run(quick="--quick" in sys.argv))
