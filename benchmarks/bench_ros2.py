"""`terrainml predict` over loopback DDS (ROS 2 source and sink) at 100 Hz, beside UDP JSON.

One run, two transports, the same simulated 100 Hz drive (dry sand, straight), the same model:

* **ROS 2**: this process publishes the log's messages onto DDS (cyclonedds, the rmw_cyclonedds
  wire format), paced at their log times, and subscribes to ``/terrainml/desired_slip``; ``terrainml
  predict --source ros2://D?qos=reliable --sink ros2://D`` runs as its own process. Latency of tick
  k: reception of its desired slip minus the publication of the last message tick k needed (the
  first message after the tick of every topic: the aligner decides a tick once every source has a
  sample after it, so one base period of alignment delay, 10 ms, comes before this and is not
  counted).
* **UDP JSON**: the same ticks as samples (the ingested table's rows, one JSON datagram per tick)
  to ``--source udp://`` and desired slip back from ``--sink udp://``; latency: reception minus
  sending of the tick's sample.

CPU share: the predict process's user + system CPU time over the streaming wall time (100% = one
core). Aligner CPU per tick: the same messages decoded as the source decodes them and fed to the live
aligner message by message without DDS (process time per tick served; no other work). The first
second of ticks (warm-up, start-up bursts) is not counted. Both transports run on
loopback (CYCLONEDDS_URI: interface ``lo``, multicast off) with a domain id of their own.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

RATE_HZ = 100.0
LOOPBACK = ('<CycloneDDS><Domain><General><Interfaces><NetworkInterface name="lo"/></Interfaces>'
            '<AllowMulticast>false</AllowMulticast></General><Discovery><ParticipantIndex>auto</ParticipantIndex>'
            '<MaxAutoParticipantIndex>30</MaxAutoParticipantIndex><Peers><Peer address="127.0.0.1"/></Peers>'
            '</Discovery></Domain></CycloneDDS>')
PREDICT = [sys.executable, "-m", "terrainml.cli", "predict"]
INPUT_TYPES = {"/imu": "Imu", "/camera/odom/sample": "Odometry", "/wheels/joint_states": "JointState",
               "/wheels/motor_current": "JointState", "/cmd_vel": "Twist"}


def _model(tmp: str) -> str:
    """A small SVM from the `make demo` chain (2 simulated runs per class, 20 s)."""
    from terrainml.pipeline.dataset import build_dataset
    from terrainml.pipeline.train_options import TrainOptions
    from terrainml.pipeline.train import train
    from terrainml.robot import load_robot
    from terrainml.sim.generate import generate_dataset

    logs = os.path.join(tmp, "logs")
    generate_dataset(logs, 2, seed=2024, n_jobs=1, duration_s=20.0, fmt="parquet")
    ds = build_dataset(logs, load_robot(), n_jobs=1)
    out = os.path.join(tmp, "model")
    train(ds, out, models=("svm",), options=TrainOptions(folds=2, seed=0, n_jobs=1, ablation=False))
    return out


def _messages(path: Path) -> list[tuple[str, int, object]]:
    """(topic, log time ns, IDL message) of the mapped inputs in log order: each MCAP payload is the
    XCDR1 the DDS writer sends, deserialised by the IDL class of its type."""
    from mcap.reader import make_reader

    from terrainml.stream.transports.ros2 import types as T

    out = []
    with open(path, "rb") as fh:
        for _, ch, m in make_reader(fh).iter_messages(topics=list(INPUT_TYPES), log_time_order=True):
            out.append((ch.topic, m.log_time, getattr(T, INPUT_TYPES[ch.topic]).deserialize(m.data)))
    return out


def _proc_cpu_s(pid: int) -> float:
    import psutil

    t = psutil.Process(pid).cpu_times()
    return t.user + t.system


def _wait_ready(proc: subprocess.Popen, err: Path, timeout_s: float = 300.0) -> None:
    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end:
        if "ready" in err.read_text():
            return
        if proc.poll() is not None:
            break
        time.sleep(0.1)
    raise RuntimeError(f"predict did not start: {err.read_text()[-2000:]}")


def _settle_pub_ns(msgs, pub_ns: np.ndarray, t0_ns: int, n_ticks: int) -> np.ndarray:
    """Per tick: publication time of the last message it needed (every topic's first after the tick)."""
    out = np.zeros(n_ticks, np.int64)
    for topic in INPUT_TYPES:
        idx = [i for i, (tp, _, _) in enumerate(msgs) if tp == topic]
        if not idx:
            continue
        stamps = np.array([_stamp(msgs[i]) for i in idx]) - t0_ns
        ticks = np.arange(n_ticks) * (1e9 / RATE_HZ)
        j = np.searchsorted(stamps, ticks + 1.0, side="left")
        ok = j < len(idx)
        pub = np.where(ok, pub_ns[np.array(idx)][np.clip(j, 0, len(idx) - 1)], np.iinfo(np.int64).max)
        out = np.maximum(out, pub)
    return out


def _stamp(m) -> int:
    topic, log_ns, msg = m
    h = getattr(msg, "header", None)
    if h is None:
        return log_ns
    t = h.stamp.sec * 1_000_000_000 + h.stamp.nanosec
    return t if t > 0 else log_ns


def _ros2_run(model: str, log: Path, tmp: Path, domain: int) -> dict:
    from cyclonedds.core import ReadCondition, SampleState, WaitSet
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.pub import DataWriter
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic
    from cyclonedds.util import duration

    from terrainml.stream.transports.ros2.names import dds_topic_name, qos_for
    from terrainml.stream.transports.ros2.types import Float64MultiArray

    msgs = _messages(log)
    dp = DomainParticipant(domain)
    writers = {tp: DataWriter(dp, Topic(dp, dds_topic_name(tp), type(m)), qos=qos_for("reliable"))
               for tp, _, m in {m[0]: m for m in msgs}.values()}
    reader = DataReader(dp, Topic(dp, dds_topic_name("/terrainml/desired_slip"), Float64MultiArray),
                        qos=qos_for("reliable"))
    err = tmp / "ros2.err"
    proc = subprocess.Popen(PREDICT + ["--model", model, "--source", f"ros2://{domain}?qos=reliable&discovery_s=5",
                                       "--sink", f"ros2://{domain}", "--idle-timeout-s", "3"],
                            stdout=subprocess.DEVNULL, stderr=open(err, "w"), env=os.environ.copy())
    _wait_ready(proc, err)
    while not all(w.get_matched_subscriptions() for w in writers.values()) or not reader.get_matched_publications():
        time.sleep(0.05)
    time.sleep(1.0)
    recv: list[int] = []
    stop = threading.Event()

    def rx():
        ws = WaitSet(dp)
        ws.attach(ReadCondition(reader, SampleState.NotRead))
        while not stop.is_set():
            ws.wait(duration(milliseconds=50))
            for _ in reader.take(100):
                recv.append(time.monotonic_ns())

    th = threading.Thread(target=rx, daemon=True)
    th.start()
    pub_ns = np.zeros(len(msgs), np.int64)
    t0_log = msgs[0][1]
    cpu0, w0 = _proc_cpu_s(proc.pid), time.monotonic()
    start = time.monotonic_ns()
    for i, (tp, log_ns, m) in enumerate(msgs):
        due = start + (log_ns - t0_log)
        while (now := time.monotonic_ns()) < due:
            time.sleep(min((due - now) * 1e-9, 0.002))
        writers[tp].write(m, timestamp=log_ns)
        pub_ns[i] = time.monotonic_ns()
    time.sleep(0.5)
    cpu1, w1 = _proc_cpu_s(proc.pid), time.monotonic()
    proc.wait(timeout=120)
    stop.set()
    th.join(timeout=5)
    t0 = min(_stamp(m) for m in msgs)
    n = len(recv)
    settle = _settle_pub_ns(msgs, pub_ns, t0, n)
    lat_ms = (np.array(recv) - settle) * 1e-6
    keep = np.arange(n) >= int(RATE_HZ)
    keep &= settle < np.iinfo(np.int64).max
    return {"lat_ms": lat_ms[keep], "ticks": n, "cpu": (cpu1 - cpu0) / (w1 - w0), "stderr": err.read_text()}


#: a process that writes every Float64MultiArray it takes from rt/bench/ping back on rt/bench/pong,
#: woken by a WaitSet as the ROS 2 source is: two DDS hops and Python's cyclonedds, no terrainml
ECHO = """
import sys
from cyclonedds.core import ReadCondition, SampleState, WaitSet
from cyclonedds.domain import DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration
from terrainml.stream.transports.ros2.names import qos_for
from terrainml.stream.transports.ros2.types import Float64MultiArray
dp = DomainParticipant(int(sys.argv[1]))
r = DataReader(dp, Topic(dp, "rt/bench/ping", Float64MultiArray), qos=qos_for("reliable"))
w = DataWriter(dp, Topic(dp, "rt/bench/pong", Float64MultiArray), qos=qos_for("reliable"))
ws = WaitSet(dp)
ws.attach(ReadCondition(r, SampleState.NotRead))
print("ready", file=sys.stderr, flush=True)
idle = 0
while idle < 30:
    ws.wait(duration(milliseconds=100))
    got = r.take(256)
    idle = 0 if got else idle + 1
    for m in got:
        w.write(m)
"""


def _echo_run(domain: int, n: int) -> np.ndarray:
    """Latency (ms) of a 100 Hz message through the echo process and back over loopback DDS."""
    from cyclonedds.core import ReadCondition, SampleState, WaitSet
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.pub import DataWriter
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic
    from cyclonedds.util import duration

    from terrainml.stream.transports.ros2.names import qos_for
    from terrainml.stream.transports.ros2.types import Float64MultiArray

    proc = subprocess.Popen([sys.executable, "-c", ECHO, str(domain)], stderr=subprocess.PIPE, text=True,
                            env=os.environ.copy())
    assert "ready" in proc.stderr.readline()
    dp = DomainParticipant(domain)
    w = DataWriter(dp, Topic(dp, "rt/bench/ping", Float64MultiArray), qos=qos_for("reliable"))
    r = DataReader(dp, Topic(dp, "rt/bench/pong", Float64MultiArray), qos=qos_for("reliable"))
    while not w.get_matched_subscriptions() or not r.get_matched_publications():
        time.sleep(0.05)
    time.sleep(1.0)
    recv: dict[int, int] = {}
    stop = threading.Event()

    def rx():
        ws = WaitSet(dp)
        ws.attach(ReadCondition(r, SampleState.NotRead))
        while not stop.is_set():
            ws.wait(duration(milliseconds=50))
            for m in r.take(100):
                recv[int(m.data[0])] = time.monotonic_ns()

    th = threading.Thread(target=rx, daemon=True)
    th.start()
    sent = np.zeros(n, np.int64)
    start = time.monotonic_ns()
    for k in range(n):
        due = start + int(k * 1e9 / RATE_HZ)
        while (now := time.monotonic_ns()) < due:
            time.sleep(min((due - now) * 1e-9, 0.002))
        sent[k] = time.monotonic_ns()
        w.write(Float64MultiArray(data=[float(k), 0.0, 0.0]))
    time.sleep(0.5)
    stop.set()
    th.join(timeout=5)
    proc.wait(timeout=30)
    ks = np.array(sorted(k for k in recv if k >= int(RATE_HZ)))
    return (np.array([recv[k] for k in ks]) - sent[ks]) * 1e-6


def _aligner_ms_per_tick(log: Path) -> float:
    """CPU (ms) per tick of the live aligner on the log's inputs, one message at a time, no DDS."""
    from terrainml.io import cdr
    from terrainml.io.topicmap import load_topic_map
    from terrainml.robot import load_robot
    from terrainml.stream.transports.ros2.align import LiveAligner

    tmap = load_topic_map(None)
    by = tmap.by_topic()
    parts = [(tp, cdr.from_object(by[tp].decode_kind, m, log_ns)) for tp, log_ns, m in _messages(log)]
    al = LiveAligner(tmap, load_robot(), RATE_HZ, name="bench", warmup_wait_s=0.0, required=list(INPUT_TYPES))
    n, t0 = 0, time.process_time()
    for tp, part in parts:
        al.add(tp, part)
        n += len(al.poll())
    n += len(al.finish())
    return (time.process_time() - t0) * 1e3 / max(n, 1)


def _udp_run(model: str, log: Path, tmp: Path) -> dict:
    from terrainml.io.ingest import load_run
    from terrainml.stream.transports.sources import iter_table_samples

    samples = [s.columns for s in iter_table_samples(load_run(log).table)]   # JSON objects, as sent
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 * 2**20)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(0.5)
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    in_port = s.getsockname()[1]
    s.close()
    err = tmp / "udp.err"
    proc = subprocess.Popen(PREDICT + ["--model", model, "--source", f"udp://127.0.0.1:{in_port}",
                                       "--sink", f"udp://127.0.0.1:{rx.getsockname()[1]}", "--idle-timeout-s", "3"],
                            stdout=subprocess.DEVNULL, stderr=open(err, "w"), env=os.environ.copy())
    _wait_ready(proc, err)
    time.sleep(1.0)
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    recv: dict[int, int] = {}
    stop = threading.Event()

    def rxloop():
        while not stop.is_set():
            try:
                data = rx.recv(65535)
            except socket.timeout:
                continue
            recv[json.loads(data)["seq"]] = time.monotonic_ns()

    th = threading.Thread(target=rxloop, daemon=True)
    th.start()
    sent = np.zeros(len(samples), np.int64)
    cpu0, w0 = _proc_cpu_s(proc.pid), time.monotonic()
    start = time.monotonic_ns()
    for k, smp in enumerate(samples):
        due = start + int(k * 1e9 / RATE_HZ)
        while (now := time.monotonic_ns()) < due:
            time.sleep(min((due - now) * 1e-9, 0.002))
        data = json.dumps(smp).encode()
        sent[k] = time.monotonic_ns()
        tx.sendto(data, ("127.0.0.1", in_port))
    time.sleep(0.5)
    cpu1, w1 = _proc_cpu_s(proc.pid), time.monotonic()
    proc.wait(timeout=120)
    stop.set()
    th.join(timeout=5)
    ks = np.array(sorted(k for k in recv if k >= int(RATE_HZ)))
    lat = (np.array([recv[k] for k in ks]) - sent[ks]) * 1e-6
    return {"lat_ms": lat, "ticks": len(recv), "cpu": (cpu1 - cpu0) / (w1 - w0), "stderr": err.read_text()}


def run(quick: bool = False) -> str:
    from terrainml.sim.generate import simulate
    from terrainml.sim.output import write_mcap

    from benchmarks.run_all import machine_description

    os.environ.setdefault("CYCLONEDDS_URI", LOOPBACK)
    duration_s = 10.0 if quick else 30.0
    with tempfile.TemporaryDirectory() as tmp_s:
        tmp = Path(tmp_s)
        t0 = time.perf_counter()
        model = _model(tmp_s)
        t_model = time.perf_counter() - t0
        log = tmp / "drive.mcap"
        write_mcap(simulate("dry_sand", "straight", duration_s=duration_s, seed=77), log)
        ros = _ros2_run(model, log, tmp, domain=150 + os.getpid() % 50)
        udp = _udp_run(model, log, tmp)
        align_ms = _aligner_ms_per_tick(log)
        echo = _echo_run(100 + os.getpid() % 50, int(duration_s * RATE_HZ))
    p = {k: np.percentile(r["lat_ms"], [50, 99]) if len(r["lat_ms"]) else np.array([np.nan, np.nan])
         for k, r in (("ros", ros), ("udp", udp))}
    rows = [
        "| transport | ticks received | latency p50 / p99 (ms) | max (ms) | CPU share of one core |",
        "|---|---|---|---|---|",
        f"| ROS 2 over loopback DDS (cyclonedds, reliable) | {ros['ticks']} | {p['ros'][0]:.2f} / {p['ros'][1]:.2f} "
        f"| {np.max(ros['lat_ms']):.1f} | {100 * ros['cpu']:.0f}% |",
        f"| UDP JSON | {udp['ticks']} | {p['udp'][0]:.2f} / {p['udp'][1]:.2f} | {np.max(udp['lat_ms']):.1f} "
        f"| {100 * udp['cpu']:.0f}% |",
        f"| ratio ROS 2 / UDP | | {p['ros'][0] / p['udp'][0]:.1f}x / {p['ros'][1] / p['udp'][1]:.1f}x | "
        f"| {ros['cpu'] / max(udp['cpu'], 1e-9):.1f}x |",
        f"| floor: DDS echo, no terrainml (100 Hz, a message to a Python process and back) | {len(echo) + 100} | "
        f"{np.percentile(echo, 50):.2f} / {np.percentile(echo, 99):.2f} | {np.max(echo):.1f} | |",
        "",
        f"Live aligner alone (replay of the same inputs without DDS): {align_ms:.2f} ms of CPU per tick.",
    ]
    goal = "met" if p["ros"][1] <= 2.0 else "NOT met"
    return "\n".join([
        "## ROS 2 participant over DDS: publication -> desired slip at 100 Hz",
        "",
        f"Machine: {machine_description()} (2 cores shared with other jobs while this ran: wall-clock "
        "latencies, the p99 most, are pessimistic). A "
        f"{duration_s:.0f} s simulated 100 Hz drive (dry sand, straight; IMU, wheel joints, motor currents "
        "and cmd_vel at 100 Hz, T265 odometry at 200 Hz), paced at its log times; SVM trained here on 2 "
        f"simulated runs of 20 s per class ({t_model:.0f} s). Method: `benchmarks/bench_ros2.py` docstring (ROS 2 "
        "latency from the publication of the last message a tick needed; UDP from sending the tick's sample).",
        "",
        *rows,
        "",
        f"Goal p99 <= 2 ms over loopback DDS: **{goal}** ({p['ros'][1]:.2f} ms). On top of the ROS 2 "
        "figure comes one base period (10 ms) of alignment: a tick is decided once every topic has a "
        "message after it, as ingest decides it (`terrainml/stream/transports/ros2/align.py`).",
    ])


if __name__ == "__main__":
    print(run(quick="--quick" in sys.argv))
