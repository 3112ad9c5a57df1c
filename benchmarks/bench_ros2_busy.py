"""False silences of `terrainml predict` over ROS 2 while both cores are busy (docs/ros2.md).

The independent peer (``tests/stream/ros2_peer.py``: its own cyclonedds IDL classes, no terrainml
code) publishes a simulated 60-s drive (dry sand, straight) at real time over loopback DDS, with no
fault: every topic publishes throughout. ``terrainml predict --source ros2://D --sink ros2://D
--sink stdout`` serves it while CPU hogs (``--hogs-per-core`` busy loops per core, started before
the peer) keep every core busy. A *false silence* is any line of predict's log calling a topic or
a sensor group silent while the peer was publishing: predict's stderr is read when the peer exits
(it lingers 0 s after its last message, so the end of the drive is never counted). Repeated
``--runs`` times on fresh processes, each on a domain of its own.

Also reported per run: ticks served (6,000 is the drive at 100 Hz) and the share served with a
healthy estimator.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.bench_ros2 import LOOPBACK, PREDICT, _model

PEER = str(Path(__file__).resolve().parents[1] / "tests" / "stream" / "ros2_peer.py")
LOG_S = 60.0
_SILENT = re.compile(r"topic \S+ silent: no message|sensor group '\w+' silent at")


def one_run(model: str, log: Path, tmp: Path, hogs: int, domain: int) -> dict:
    """One drive under hogs: predict first, then the hogs, then the peer; predict's log at the peer's end."""
    env = {**os.environ, "CYCLONEDDS_URI": os.environ.get("CYCLONEDDS_URI", LOOPBACK), "PYTHONUNBUFFERED": "1"}
    err, out = tmp / "predict.err", tmp / "predict.out"
    pred = subprocess.Popen(PREDICT + ["--model", model, "--source", f"ros2://{domain}?qos=reliable",
                                       "--sink", f"ros2://{domain}", "--sink", "stdout", "--idle-timeout-s", "20"],
                            stdout=open(out, "w"), stderr=open(err, "w"), env=env)
    hog: list[subprocess.Popen] = []
    try:
        t_end = time.monotonic() + 300
        while "ready" not in err.read_text():
            if pred.poll() is not None or time.monotonic() > t_end:
                raise RuntimeError(f"predict did not start: {err.read_text()[-2000:]}")
            time.sleep(0.2)
        hog = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(hogs)]
        peer = subprocess.run([sys.executable, PEER, "publish", "--domain", str(domain), "--mcap", str(log),
                               "--reliable", "--linger-s", "0"], capture_output=True, text=True, env=env,
                              timeout=LOG_S * 4 + 300)
        if peer.returncode:
            raise RuntimeError(f"peer failed: {peer.stderr[-2000:]}")
        during = err.read_text()
    finally:
        for h in hog:
            h.kill()
            h.wait()
        pred.send_signal(2)       # SIGINT: predict serves what is left and prints its counters
        try:
            pred.wait(timeout=120)
        except subprocess.TimeoutExpired:
            pred.kill()
    served = [json.loads(x) for x in out.read_text().splitlines() if x.strip()]
    full = err.read_text()
    return {"false": [ln for ln in during.splitlines() if _SILENT.search(ln)], "ticks": len(served),
            "healthy": sum(m["estimator_ok"] for m in served) / max(len(served), 1),
            "tracebacks": full.count("Traceback")}


def run(runs: int = 10, hogs_per_core: int = 1, quick: bool = False) -> str:
    from benchmarks.run_all import machine_description
    from terrainml.sim.generate import simulate
    from terrainml.sim.output import write_mcap

    runs = 2 if quick else runs
    cores = os.cpu_count() or 2
    os.environ.setdefault("CYCLONEDDS_URI", LOOPBACK)
    rows = ["| run | false silences | ticks served | healthy estimator | tracebacks |", "|---|---|---|---|---|"]
    total_false, examples, wall0 = 0, [], time.monotonic()
    with tempfile.TemporaryDirectory() as tmp_s:
        tmp = Path(tmp_s)
        model = _model(tmp_s)
        log = tmp / "drive.mcap"
        write_mcap(simulate("dry_sand", "straight", duration_s=LOG_S, seed=78), log)
        for k in range(runs):
            d = tmp / f"run{k}"
            d.mkdir()
            r = one_run(model, log, d, hogs_per_core * cores, domain=100 + (os.getpid() + k) % 90)
            keep = os.environ.get("TERRAINML_BUSY_KEEP")
            if keep:   # predict's log of each run, to read the episodes
                Path(keep).mkdir(parents=True, exist_ok=True)
                (Path(keep) / f"predict{k + 1}.err").write_text((d / "predict.err").read_text())
            total_false += len(r["false"])
            examples += r["false"][:2]
            rows.append(f"| {k + 1} | {len(r['false'])} | {r['ticks']} | {100 * r['healthy']:.1f}% | "
                        f"{r['tracebacks']} |")
            print(rows[-1], file=sys.stderr, flush=True)
    return "\n".join([
        "## ROS 2: no false silence while both cores are busy",
        "",
        f"Machine: {machine_description()}. {runs} runs of a {LOG_S:.0f}-s simulated drive published by the "
        f"independent peer at real time, {hogs_per_core * cores} busy loops ({hogs_per_core} per core) beside "
        f"`predict` and the peer; {(time.monotonic() - wall0) / 60:.1f} min of wall time; method in "
        "`benchmarks/bench_ros2_busy.py`.",
        "",
        *rows,
        "",
        f"False silences: **{total_false}** in {runs} runs (goal 0){': ' if examples else ''}"
        + "; ".join(examples[:4]),
    ])


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=10)
    ap.add_argument("--hogs-per-core", type=int, default=1)
    args = ap.parse_args()
    print(run(runs=args.runs, hogs_per_core=args.hogs_per_core))
