"""Ingest benchmark: throughput on a 10-minute 5-topic ROS 2 MCAP vs rosbags, peak RSS.

Reference, same run, same file: rosbags' ``AnyReader`` reading and deserialising every message
(``reader.deserialize``, rosbags' generated CDR deserialiser) -- no resampling at all. Ours:
``terrainml.io.ingest.ingest_to_parquet`` (what ``terrainml ingest LOG --out RUN.parquet``
runs: two streaming passes, decode, T265 transform, sort, resample to 100 Hz in 30 s chunks,
Parquet row groups written) and, for reference, the in-memory ``terrainml.io.ingest.load_run``.

Peak RSS: each ingest in a fresh subprocess (VmHWM), a 1-minute and a 10-minute log; the
streaming ingest must not grow with the log length (goal: <= 10 % from 1 to 10 minutes), the
in-memory ``load_run`` necessarily does (it returns the whole table).

Run: ``.venv/bin/python -m benchmarks.run_all --only bench_ingest --out /tmp/b.md``
"""

from __future__ import annotations

import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

RATES_HZ = {"/camera/odom/sample": 200, "/imu": 100, "/wheels/joint_states": 100,
            "/wheels/motor_current": 100, "/cmd_vel": 20}


def write_log(path: Path, seconds: float, n_wheels: int = 3, seed: int = 0) -> int:
    """A 5-topic log (T265 200 Hz, IMU, joints, currents 100 Hz, cmd_vel 20 Hz) through RosMcapWriter."""
    from terrainml.io import t265
    from terrainml.io.mcap_writer import RosMcapWriter

    rng = np.random.default_rng(seed)
    n = int(seconds * 200)
    t = np.arange(n) / 200.0
    yaw = 0.1 * np.sin(0.05 * t)
    r = np.gradient(yaw, t)
    vx = 1.0 + 0.1 * np.sin(0.3 * t)
    x = np.cumsum(vx * np.cos(yaw)) / 200.0
    y = np.cumsum(vx * np.sin(yaw)) / 200.0
    cam = t265.body_to_t265_odometry(x, y, yaw, vx, np.zeros(n), r, (0.6685, -0.26875, 0.0))
    noise = rng.normal(0, 0.01, (n, 6))
    count = 0
    with RosMcapWriter(path, n_wheels) as w:
        for k in range(n):
            tk = float(t[k])
            w.write_camera_odom(tk, cam["position_m"][k], cam["orientation_xyzw"][k], cam["linear_mps"][k],
                                cam["angular_radps"][k], confidence=3.0)
            count += 1
            if k % 2 == 0:
                w.write_imu(tk, (noise[k, 0], noise[k, 1], 9.81 + noise[k, 2]), (0.0, 0.0, r[k] + noise[k, 3]))
                om = vx[k] / 0.165
                w.write_wheel_joints(tk, [om] * n_wheels, [0.0] * n_wheels)
                w.write_motor_current(tk, [2.0 + noise[k, 4]] * n_wheels)
                count += 3
            if k % 10 == 0:
                w.write_cmd_vel(tk, 1.0, 0.0, 0.0)
                count += 1
    return count


def rosbags_read(path: Path) -> tuple[int, float]:
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    t0 = time.perf_counter()
    n = 0
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
        for conn, _t, raw in reader.messages():
            reader.deserialize(raw, conn.msgtype)
            n += 1
    return n, time.perf_counter() - t0


def ours(path: Path) -> tuple[int, float, int]:
    from terrainml.io.ingest import load_run

    t0 = time.perf_counter()
    res = load_run(path)
    dt = time.perf_counter() - t0
    n = sum(d["decoded"] for d in res.report.topics.values())
    return n, dt, res.report.rows


def ours_stream(path: Path, out: Path) -> tuple[int, float, int]:
    from terrainml.io.ingest import ingest_to_parquet

    t0 = time.perf_counter()
    rep = ingest_to_parquet(path, out)
    dt = time.perf_counter() - t0
    assert rep.usable, rep.errors
    return sum(d["decoded"] for d in rep.topics.values()), dt, rep.rows


# Peak RSS of the child process. ru_maxrss survives fork+exec on Linux (a child starts with its
# parent's high-water mark), so the per-process VmHWM from /proc is read instead where it exists.
_PEAK = ("def peak():\n"
         "    import resource\n"
         "    try:\n"
         "        for ln in open('/proc/self/status'):\n"
         "            if ln.startswith('VmHWM:'):\n"
         "                return int(ln.split()[1])\n"
         "    except OSError:\n"
         "        pass\n"
         "    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss\n")
_IMPORTS = "import sys\nimport terrainml.io.ingest, pyarrow.parquet\n"
_SNIPPETS = {
    "imports": _PEAK + _IMPORTS + "print(peak())\n",
    "load_run": _PEAK + _IMPORTS + ("r = terrainml.io.ingest.load_run(sys.argv[1])\nassert r.report.usable\n"
                                    "print(peak())\n"),
    "stream": _PEAK + _IMPORTS + ("r = terrainml.io.ingest.ingest_to_parquet(sys.argv[1], sys.argv[2])\n"
                                  "assert r.usable\nprint(peak())\n"),
}


def peak_rss_mib(mode: str, path: Path | None = None, out: Path | None = None) -> float:
    """Peak resident memory (MiB) of a fresh process: ``imports``, ``load_run`` or ``stream``."""
    cmd = [sys.executable, "-c", _SNIPPETS[mode]] + [str(p) for p in (path, out) if p is not None]
    res = subprocess.run(cmd, capture_output=True, text=True)
    if res.returncode:
        raise RuntimeError(f"peak RSS child ({mode}) failed: {res.stderr[-2000:]}")
    return int(res.stdout.strip().splitlines()[-1]) / 1024.0  # KiB -> MiB


def _machine() -> str:
    try:
        cpu = next((ln.split(":", 1)[1].strip() for ln in open("/proc/cpuinfo") if ln.startswith("model name")),
                   platform.processor())
    except OSError:
        cpu = platform.processor()
    return f"{cpu}, {os.cpu_count()} cores, Python {platform.python_version()}"


def run(quick: bool = False) -> str:
    long_s = 120.0 if quick else 600.0
    short_s = 12.0 if quick else 60.0
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        long_log, short_log = tmp / "long.mcap", tmp / "short.mcap"
        out = tmp / "run.parquet"
        t0 = time.perf_counter()
        n_msgs = write_log(long_log, long_s)
        t_write = time.perf_counter() - t0
        write_log(short_log, short_s)
        # warm caches once, then measure (best of 2 for every path)
        ours(short_log)
        ours_stream(short_log, out)
        rosbags_read(short_log)
        o = min((ours(long_log) for _ in range(2)), key=lambda r: r[1])
        st = min((ours_stream(long_log, out) for _ in range(2)), key=lambda r: r[1])
        rb = min((rosbags_read(long_log) for _ in range(2)), key=lambda r: r[1])
        rss_base = peak_rss_mib("imports")
        rss = {(mode, which): peak_rss_mib(mode, log, out)
               for mode in ("stream", "load_run") for which, log in (("short", short_log), ("long", long_log))}
        size_mib = long_log.stat().st_size / 2**20
    ours_rate, st_rate, rb_rate = o[0] / o[1], st[0] / st[1], rb[0] / rb[1]
    growth = rss[("stream", "long")] / rss[("stream", "short")] - 1.0
    growth_mem = rss[("load_run", "long")] / rss[("load_run", "short")] - 1.0
    sm, lm = f"{short_s / 60:g}", f"{long_s / 60:g}"
    lines = [
        "## Ingest (ROS 2 MCAP -> canonical run table)",
        "",
        f"Machine: {_machine()}. Log: {lm} min, 5 topics (T265 odometry 200 Hz, IMU, wheel joints, "
        f"motor currents 100 Hz, cmd_vel 20 Hz), {n_msgs:,} messages, {size_mib:.1f} MiB zstd "
        f"(written by RosMcapWriter in {t_write:.1f} s = {n_msgs / t_write:,.0f} msg/s).",
        "",
        "| path | messages | time s | messages/s | x real time | ratio vs rosbags |",
        "|---|---:|---:|---:|---:|---:|",
        f"| rosbags AnyReader: read + deserialize every message (reference) | {rb[0]:,} | {rb[1]:.2f} | "
        f"{rb_rate:,.0f} | {long_s / rb[1]:.0f} | 1.00 |",
        f"| terrainml `ingest --out` (ingest_to_parquet): 2 streaming passes, decode, T265, resample 100 Hz "
        f"in 30 s chunks, write Parquet | {st[0]:,} | {st[1]:.2f} | {st_rate:,.0f} | {long_s / st[1]:.0f} | "
        f"{st_rate / rb_rate:.2f} |",
        f"| terrainml load_run (in memory): read + decode + T265 + resample 100 Hz + validate | {o[0]:,} | "
        f"{o[1]:.2f} | {ours_rate:,.0f} | {long_s / o[1]:.0f} | {ours_rate / rb_rate:.2f} |",
        "",
        f"Ratio streaming ingest / rosbags (messages/s): **{st_rate / rb_rate:.2f}x** "
        f"(in-memory load_run: {ours_rate / rb_rate:.2f}x). Goal: >= 200x real time "
        f"({'met' if long_s / st[1] >= 200 else 'NOT met'}) and no slower than rosbags "
        f"({'met' if st_rate >= rb_rate else 'NOT met'}).",
        "",
        f"| peak RSS (fresh process, VmHWM), MiB | {sm}-min log | {lm}-min log | growth |",
        "|---|---:|---:|---:|",
        f"| imports only (numpy, pandas, scipy, pyarrow, terrainml.io) | {rss_base:.0f} | {rss_base:.0f} | |",
        f"| `terrainml ingest --out` (streaming, 30 s chunks) | {rss[('stream', 'short')]:.0f} | "
        f"{rss[('stream', 'long')]:.0f} | **{growth:+.1%}** |",
        f"| load_run (in memory, returns the whole table) | {rss[('load_run', 'short')]:.0f} | "
        f"{rss[('load_run', 'long')]:.0f} | {growth_mem:+.1%} |",
        "",
        f"Streaming peak RSS from the {sm}-min to the {lm}-min log: {growth:+.1%} (goal: <= +10 %, "
        f"{'met' if growth <= 0.10 else 'NOT met'}). The streaming path holds one chunk of ticks, the "
        "source samples between that chunk and the settle frontier, and constant-size per-topic facts "
        "(a slower-than-base-rate topic keeps 8 bytes per message for its median period); load_run "
        f"returns the whole table (~{o[2] * 31 * 8 / 2**20:.0f} MiB for {o[2]:,} rows) and so grows with the log.",
        "",
    ]
    return "\n".join(lines)


if __name__ == "__main__":  # pragma: no cover
    print(run(quick="--quick" in sys.argv))
