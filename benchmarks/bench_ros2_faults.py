"""Fault soak of `terrainml predict` over ROS 2: random input faults for many minutes (docs/ros2.md).

The independent peer (``tests/stream/ros2_peer.py``: its own cyclonedds IDL classes, no terrainml
code) replays a drive onto loopback DDS in a loop, stamps continuing, with a fault plan drawn from
a seeded generator: every 20-40 s one of

* ``pause``: one topic silent for 0.1-10 s (the IMU or the wheel JointState topic);
* ``pause_all``: every topic silent for 2-10 s;
* ``restart``: the publisher leaves the domain and joins as a new participant 1-3 s later;
* ``nan``: NaN velocities on one wheel joint for 2-10 s;
* ``hogs``: CPU hogs on every core (this process starts ``2 x cores`` busy loops) for 10-20 s.

The drive (``--data``):

* ``sim`` (default): a simulated 60-s drive (dry sand, straight) on the reference robot's topics
  (the default topic map), served by a small SVM from the ``make demo`` chain;
* ``borealtc``: the real BorealTC run ASPHALT_04 (49.5 s) as a Husky publishes it
  (``ros2_peer.py --borealtc``: ``/joint_states``, ``/imu/data``), served with ``--robot husky
  --topics husky_ros2`` by the Husky model of ``tests/stream/test_ros2_borealtc.py`` (an SVM on
  chunks windows of wheels and IMU, three runs with IMU per class, the replayed run left out); the
  paused topic is ``/imu/data`` or ``/joint_states``, the NaN joint a left wheel's.

``terrainml predict --source ros2://D --sink ros2://D --sink stdout`` serves it (the ROS 2 sink
with its diagnostics timer runs; what it publishes is checked by the interop tests). Truth is
``predict --source LOG`` on one pass of the same drive as a log file (the simulator's MCAP; for
BorealTC the MCAP that ``ros2_peer.py write`` makes of the same messages, which a fault-free DDS
pass serves identically, tick for tick): the class it serves at each log time. Per fault
kind:

* **recovery**: from the end of the fault (the topic's first message after a pause) to the first
  tick that serves the offline class again with a healthy estimator, s of stream time (p50 /
  p99); a fault whose next 20 s never serve it counts as not recovered;
* **false silences**: "silent" log lines for a topic while the plan had it publishing (goal 0);
* **served right**: share of ticks serving the offline class, in the 20 s before the fault and
  from 3 s to 20 s after its end;
* **ticks lost**: ticks of log time outside every pause that were never served;
* **tracebacks** in predict's stderr (goal 0).
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from benchmarks.bench_ros2 import LOOPBACK, PREDICT, _model

ROOT = Path(__file__).resolve().parents[1]
PEER = str(ROOT / "tests" / "stream" / "ros2_peer.py")
BOREAL = ROOT.parent / "shared" / "datasets" / "borealtc"
BOREAL_RUN = ("ASPHALT", "04")
LOG_S = 60.0
KINDS = ("pause", "pause_all", "restart", "nan", "hogs")


@dataclass
class Drive:
    """What the soak replays: the peer's source options, predict's robot options, its topics."""

    describe: str
    log_s: float
    source: list[str]
    predict: list[str] = field(default_factory=list)
    pause_topics: tuple[str, ...] = ("/imu", "/wheels/joint_states")
    nan_joints: tuple[str, ...] = ("wheel1_drive", "wheel2_drive", "wheel3_drive")


def fault_plan(total_s: float, seed: int, pause_topics=("/imu", "/wheels/joint_states"),
               nan_joints=("wheel1_drive", "wheel2_drive", "wheel3_drive")) -> list[dict]:
    """Faults every 20-40 s of log time, kinds in turn from a seeded shuffle (log seconds)."""
    rng = np.random.default_rng(seed)
    out, t = [], 15.0
    while t < total_s - 25.0:
        kind = KINDS[len(out) % len(KINDS)] if len(out) < len(KINDS) else str(rng.choice(KINDS))
        if kind == "pause":
            f = {"kind": "pause", "topic": str(rng.choice(list(pause_topics))),
                 "dur_s": float(np.round(10 ** rng.uniform(-1, 1), 2))}
        elif kind == "pause_all":
            f = {"kind": "pause", "topic": "all", "dur_s": float(np.round(rng.uniform(2, 10), 1))}
        elif kind == "restart":
            f = {"kind": "restart", "dur_s": float(np.round(rng.uniform(1, 3), 1))}
        elif kind == "nan":
            f = {"kind": "nan", "joint": nan_joints[int(rng.integers(0, len(nan_joints)))],
                 "dur_s": float(np.round(rng.uniform(2, 10), 1))}
        else:
            f = {"kind": "hogs", "dur_s": float(np.round(rng.uniform(10, 20), 1))}
        f["at_s"] = float(np.round(t, 2))
        out.append(f)
        t += f["dur_s"] + float(rng.uniform(20, 40))
    return out


def _label(f: dict) -> str:
    return "pause_all" if f["kind"] == "pause" and f["topic"] == "all" else f["kind"]


def _hogs(plan: list[dict], started: threading.Event, t0: list[float], stop: threading.Event) -> None:
    """Start ``2 x cores`` busy loops over each hogs fault (wall time from the peer's start)."""
    started.wait()
    for f in (f for f in plan if f["kind"] == "hogs"):
        while not stop.is_set() and time.monotonic() - t0[0] < f["at_s"]:
            time.sleep(0.05)
        if stop.is_set():
            return
        hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(2 * (os.cpu_count() or 2))]
        while not stop.is_set() and time.monotonic() - t0[0] < f["at_s"] + f["dur_s"]:
            time.sleep(0.05)
        for h in hogs:
            h.kill()
            h.wait()


def soak(model: str, drive: Drive, tmp: Path, loops: int, seed: int, domain: int) -> dict:
    env = {**os.environ, "CYCLONEDDS_URI": os.environ.get("CYCLONEDDS_URI", LOOPBACK), "PYTHONUNBUFFERED": "1"}
    total_s = loops * (drive.log_s + 0.01)
    plan = fault_plan(total_s, seed, drive.pause_topics, drive.nan_joints)
    (tmp / "faults.json").write_text(json.dumps([f for f in plan if f["kind"] != "hogs"]))
    err = tmp / "predict.err"
    out = tmp / "predict.out"
    pred = subprocess.Popen(PREDICT + ["--model", model, "--source", f"ros2://{domain}?qos=reliable&discovery_s=5",
                                       "--sink", f"ros2://{domain}", "--sink", "stdout", "--idle-timeout-s", "30",
                                       *drive.predict],
                            stdout=open(out, "w"), stderr=open(err, "w"), env=env)
    t_end = time.monotonic() + 600
    while "ready" not in err.read_text():
        if pred.poll() is not None or time.monotonic() > t_end:
            raise RuntimeError(f"predict did not start: {err.read_text()[-2000:]}")
        time.sleep(0.2)
    peer_err = tmp / "peer.err"
    peer = subprocess.Popen([sys.executable, PEER, "publish", "--domain", str(domain), *drive.source, "--reliable",
                             "--loop", str(loops), "--faults", str(tmp / "faults.json")],
                            stdout=subprocess.DEVNULL, stderr=open(peer_err, "w"), env=env)
    started, stop, t0 = threading.Event(), threading.Event(), [0.0]
    th = threading.Thread(target=_hogs, args=(plan, started, t0, stop), daemon=True)
    th.start()
    while "peer: publishing" not in peer_err.read_text():
        if peer.poll() is not None:
            raise RuntimeError(f"peer failed: {peer_err.read_text()[-2000:]}")
        time.sleep(0.05)
    t0[0] = time.monotonic()
    started.set()
    try:
        peer.wait(timeout=total_s * 3 + 600)
        pred.wait(timeout=600)
    finally:
        stop.set()
        th.join(timeout=30)
        for p in (peer, pred):
            if p.poll() is None:
                p.kill()
    served = [json.loads(x) for x in out.read_text().splitlines() if x.strip()]
    return {"plan": plan, "served": served, "stderr": err.read_text(), "code": pred.returncode,
            "wall_s": time.monotonic() - t0[0]}


def _offline(model: str, log: Path, predict_args=()) -> dict[int, str]:
    out = subprocess.run(PREDICT + ["--model", model, "--source", str(log), "--sink", "stdout", *predict_args],
                         capture_output=True, text=True, timeout=1200)
    if out.returncode:
        raise RuntimeError(out.stderr[-2000:])
    return {int(round(m["t_s"] * 100)): m["terrain_name"] for m in map(json.loads, out.stdout.splitlines())}


def analyse(res: dict, offline: dict[int, str]) -> dict[str, dict]:
    """Per fault kind: recovery times, served-right shares, false silences, ticks lost (module docstring)."""
    period = len(offline) + 1          # ticks per loop (a loop starts one period after the last tick)
    by_tick = {int(round(m["t_s"] * 100)): m for m in res["served"]}

    def right(k: int) -> bool:
        m = by_tick.get(k)
        return (m is not None and m["estimator_ok"] and not m["fallback"]
                and m["terrain_name"] == offline.get(k % period))

    def share(a_s: float, b_s: float) -> float:
        ks = [k for k in range(int(a_s * 100), int(b_s * 100))
              if k in by_tick and offline.get(k % period, "none") != "none"]
        return sum(right(k) for k in ks) / max(len(ks), 1)

    paused = set()
    for f in res["plan"]:
        if f["kind"] == "restart" or (f["kind"] == "pause" and f["topic"] == "all"):   # no tick exists then
            paused.update(range(int(f["at_s"] * 100), int((f["at_s"] + f["dur_s"]) * 100) + 1))
    out: dict[str, dict] = {}
    for f in res["plan"]:
        d = out.setdefault(_label(f), {"n": 0, "recovery_s": [], "not_recovered": 0, "before": [], "after": []})
        d["n"] += 1
        end = f["at_s"] + f["dur_s"]
        rec = next((k / 100 - end for k in range(int(end * 100), int((end + 20) * 100)) if right(k)), None)
        if rec is None:
            d["not_recovered"] += 1
        else:
            d["recovery_s"].append(max(rec, 0.0))
        d["before"].append(share(f["at_s"] - 20, f["at_s"]))
        d["after"].append(share(end + 3, end + 20))
    last = max(by_tick) if by_tick else 0
    expected = [k for k in range(100, last) if k not in paused and offline.get(k % period) is not None]
    lost = sum(k not in by_tick for k in expected)
    silences = re.findall(r"topic (\S+) silent: no message", res["stderr"]) + re.findall(
        r"sensor group '(\w+)' silent at t=([\d.]+)", res["stderr"])
    false = []
    for s in silences:
        if isinstance(s, tuple):
            t = float(s[1])
            if not any(f["at_s"] - 0.5 <= t <= f["at_s"] + f["dur_s"] + 1.0 for f in res["plan"]
                       if f["kind"] in ("pause", "restart")):
                false.append(f"{s[0]} at t={t:.2f} s")
    return {"kinds": out, "lost": lost, "expected": len(expected), "false_silences": false,
            "tracebacks": res["stderr"].count("Traceback")}


def _sim_drive(tmp: Path) -> tuple[str, Drive, Path]:
    """The make-demo model and a simulated 60-s drive (its MCAP is the peer's source and the truth's log)."""
    from terrainml.sim.generate import simulate
    from terrainml.sim.output import write_mcap

    log = tmp / "drive.mcap"
    write_mcap(simulate("dry_sand", "straight", duration_s=LOG_S, seed=78), log)
    drive = Drive(f"a simulated drive (dry sand, straight, {LOG_S:.0f} s)", LOG_S, ["--mcap", str(log)])
    return _model(str(tmp)), drive, log


def _boreal_drive(tmp: Path) -> tuple[str, Drive, Path]:
    """The Husky model (trained without the replayed run) and the BorealTC run on Husky topics;
    the truth's log is the MCAP the peer writes of the same messages."""
    from terrainml.experiments.borealtc import runs_with_imu
    from terrainml.features.windows import window_spec
    from terrainml.io.ingest import load_dataset
    from terrainml.pipeline.dataset import build_from_tables
    from terrainml.pipeline.train import train
    from terrainml.pipeline.train_options import TrainOptions
    from terrainml.robot import load_robot

    label, run_id = BOREAL_RUN
    husky = load_robot("husky")
    tables, _ = load_dataset("borealtc", BOREAL)
    ds = build_from_tables(runs_with_imu(tables, 3, exclude=[f"{label}_{run_id}"]), husky,
                           spec=window_spec("chunks").resolve(husky, ["wheels", "imu"]))
    model = tmp / "husky"
    train(ds, model, ["svm"], TrainOptions(folds=2, seed=0, ablation=False,
                                           model_params={"svm": {"C_grid": (10.0,), "gamma_grid": ("scale",)}}))
    source = ["--borealtc", f"{BOREAL / label}:{run_id}"]
    log = tmp / "boreal.mcap"
    subprocess.run([sys.executable, PEER, "write", *source, "--out", str(log)], check=True, capture_output=True,
                   timeout=300)
    from mcap.reader import make_reader

    with open(log, "rb") as fh:
        st = make_reader(fh).get_summary().statistics
    # the stamps' span up to the next 10-ms tick: the peer loops every log_s + 10 ms, as on the simulated log
    log_s = -(-(st.message_end_time - st.message_start_time) // 10_000_000) / 100
    drive = Drive(f"the real BorealTC run {label}_{run_id} ({log_s:.1f} s) on a Husky's topics (husky_ros2)",
                  log_s, source, ["--robot", "husky", "--topics", "husky_ros2"], ("/imu/data", "/joint_states"),
                  ("front_left_wheel_joint", "rear_left_wheel_joint"))
    return str(model), drive, log


def run(quick: bool = False, minutes: float | None = None, seed: int = 7, data: str = "sim") -> str:
    from benchmarks.run_all import machine_description

    os.environ.setdefault("CYCLONEDDS_URI", LOOPBACK)
    minutes = minutes if minutes is not None else float(os.environ.get("TERRAINML_SOAK_MIN", 3 if quick else 20))
    with tempfile.TemporaryDirectory() as tmp_s:
        tmp = Path(tmp_s)
        model, drive, log = (_boreal_drive if data == "borealtc" else _sim_drive)(tmp)
        loops = max(1, int(round(minutes * 60 / drive.log_s)))
        offline = _offline(model, log, drive.predict)
        res = soak(model, drive, tmp, loops, seed, domain=60 + os.getpid() % 40)
        a = analyse(res, offline)
        keep = os.environ.get("TERRAINML_SOAK_KEEP")
        if keep:   # predict's stderr and the plan, to read the episodes
            Path(keep).mkdir(parents=True, exist_ok=True)
            (Path(keep) / "predict.err").write_text(res["stderr"])
            (Path(keep) / "plan.json").write_text(json.dumps(res["plan"], indent=1))
    rows = ["| fault kind | faults | recovery p50 / p99 (s) | not recovered | served right before / after |",
            "|---|---|---|---|---|"]
    for kind in KINDS:
        d = a["kinds"].get(kind)
        if d is None:
            continue
        r = np.array(d["recovery_s"])
        pr = f"{np.percentile(r, 50):.2f} / {np.percentile(r, 99):.2f}" if len(r) else "-"
        rows.append(f"| {kind} | {d['n']} | {pr} | {d['not_recovered']} | "
                    f"{100 * np.mean(d['before']):.0f}% / {100 * np.mean(d['after']):.0f}% |")
    return "\n".join([
        "## ROS 2 fault soak: random input faults over DDS",
        "",
        f"Machine: {machine_description()}. {loops} x {drive.describe} "
        f"replayed by the independent peer at real time ({res['wall_s'] / 60:.1f} min of wall time), fault plan "
        f"seed {seed}; method in `benchmarks/bench_ros2_faults.py`. predict exit code {res['code']}.",
        "",
        *rows,
        "",
        f"False silences: {len(a['false_silences'])} (goal 0){': ' if a['false_silences'] else ''}"
        f"{', '.join(a['false_silences'][:10])}. Ticks lost outside total pauses: {a['lost']} of "
        f"{a['expected']}. Tracebacks: {a['tracebacks']} (goal 0).",
    ])


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser()
    ap.add_argument("--minutes", type=float, default=20.0)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--data", choices=["sim", "borealtc"], default="sim",
                    help="sim: a simulated drive on the reference robot; borealtc: a real BorealTC run on Husky topics")
    args = ap.parse_args()
    print(run(minutes=args.minutes, seed=args.seed, data=args.data))
