"""`terrainml predict` end to end as a subprocess: UDP in, UDP out; stdin in, stdout out."""

from __future__ import annotations

import json
import math
import os
import socket
import subprocess
import sys
import time

import pytest
from mcap_damage import corrupt_middle_chunk
from stream_fakes import SLIP_OF

from terrainml.testing import kinematic_run, trapezoid_speed
from terrainml.robot import load_robot
from terrainml.stream.transports.sources import iter_table_samples

CMD = [sys.executable, "-m", "terrainml.cli", "predict"]


def _free_udp_port() -> int:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def _drive(cid: int, duration_s: float, seed: int = 7):
    robot = load_robot()
    table = kinematic_run(robot, duration_s=duration_s, slip=SLIP_OF[cid], terrain=cid, seed=seed,
                          imu_acc_noise=0.005, vx=lambda t: trapezoid_speed(t, 1.0, 1.0, 0.5),
                          run_id="e2e")
    table = table.drop(columns=[c for c in table.columns if c.startswith("gt_")] + ["terrain"])
    return [dict(s.columns) for s in iter_table_samples(table)]  # JSON objects, as sent


def _wait_ready(proc, timeout_s=60.0) -> str:
    t_end = time.time() + timeout_s
    seen = ""
    while time.time() < t_end:
        line = proc.stderr.readline()
        if not line:
            break
        seen += line
        if "ready" in line:
            return seen
    proc.kill()
    raise AssertionError(f"predict did not become ready; stderr:\n{seen}{proc.stderr.read()}")


@pytest.mark.acceptance
def test_udp_in_udp_out_one_message_per_tick_in_order(model_dir):
    samples = _drive(5, 10.0)
    assert len(samples) == 1000
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 * 2**20)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(30.0)
    out_port = rx.getsockname()[1]
    in_port = _free_udp_port()
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(CMD + ["--model", str(model_dir), "--source", f"udp://127.0.0.1:{in_port}",
                                   "--sink", f"udp://127.0.0.1:{out_port}", "--idle-timeout-s", "20"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        _wait_ready(proc)
        tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        got = []
        for k, s in enumerate(samples):
            tx.sendto(json.dumps(s).encode(), ("127.0.0.1", in_port))
            if k % 20 == 19:
                time.sleep(0.005)  # bursty sender, faster than real time
        tx.sendto(b'{"eos": true}', ("127.0.0.1", in_port))
        while len(got) < len(samples):
            got.append(json.loads(rx.recv(65535)))
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
        rx.close()
    err = proc.stderr.read()
    assert proc.returncode == 0, err
    assert [m["seq"] for m in got] == list(range(1000))
    assert [m["t_s"] for m in got] == pytest.approx([s["t_s"] for s in samples])
    assert all(len(m["slip_desired"]) == 3 and len(m["class_probabilities"]) == 8 for m in got)
    # start-up fallback until the first steady window, then the driven class (5) is served
    assert got[0]["fallback"] and got[0]["fallback_reason"] == "no_classification"
    last = got[-1]
    assert not last["fallback"] and last["terrain_class"] == 5 and last["terrain_name"] == "tilled_loam"
    assert last["estimator_ok"] and last["classification_age_s"] >= 0
    assert "1000 messages" in err


@pytest.mark.acceptance
def test_stdin_in_stdout_out_json_lines_only(model_dir):
    samples = _drive(2, 3.0)
    lines = [json.dumps(s) for s in samples]
    lines.insert(5, "this is not json")
    lines.insert(9, json.dumps(samples[7]))  # a duplicate time stamp
    proc = subprocess.run(CMD + ["--model", str(model_dir), "--source", "-", "--sink", "stdout"],
                          input="\n".join(lines) + "\n", capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    out = [json.loads(x) for x in proc.stdout.splitlines()]  # every stdout line is a message
    assert len(out) == len(samples)
    assert all(math.isfinite(v) for m in out for v in m["slip_desired"] + m["slip_measured"])
    assert "malformed input: 1" in proc.stderr and "1 duplicate" in proc.stderr


@pytest.mark.acceptance
def test_unusable_model_or_sink_exits_2_with_a_clear_message(tmp_path, model_dir, capsys):
    from terrainml.stream.app.options import ServeOptions
    from terrainml.stream.app.runner import run_predict

    # in-process for speed: the exit code and the message naming the culprit
    assert run_predict(ServeOptions(model=tmp_path / "nope", source="-", sinks=("stdout",))) == 2
    assert "nope" in capsys.readouterr().err
    assert run_predict(ServeOptions(model=model_dir, source="-", sinks=("tcp://x",))) == 2
    assert "tcp://x" in capsys.readouterr().err
    assert run_predict(ServeOptions(model=model_dir, source=str(tmp_path / "missing.mcap"), sinks=("stdout",))) == 2
    assert "missing.mcap" in capsys.readouterr().err
    # and once through the real entry point: exit code 2, no traceback
    r = subprocess.run(CMD + ["--model", str(tmp_path / "nope"), "--source", "-"],
                       input="", capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "nope" in r.stderr and "Traceback" not in r.stderr


def test_tampered_model_is_refused(tmp_path, model_dir, capsys):
    import shutil

    bad = tmp_path / "tampered"
    shutil.copytree(model_dir, bad)
    f = bad / "desired_slip_table.json"
    f.write_text(f.read_text().replace("0", "1", 1))
    from terrainml.stream.app.options import ServeOptions
    from terrainml.stream.app.runner import run_predict

    assert run_predict(ServeOptions(model=bad, source="-", sinks=("stdout",))) == 2
    assert "desired_slip_table.json" in capsys.readouterr().err


@pytest.mark.acceptance
def test_hostile_stdin_never_stops_predict(model_dir):
    """Deep nesting, huge numbers, binary, NaN, an over-long line, a wild and an absurd
    first stamp: no traceback, exit 0, one finite message per tick, live warnings, counts."""
    samples = _drive(2, 8.0)
    good = [json.dumps(s).encode() for s in samples]
    hostile = [b"[" * 1100, b'{"t_s": 1%s}' % (b"0" * 400), b'{"t_s": 1.0, "imu_ax_mps2": 1%s}' % (b"0" * 400),
               b'{"t_s": 1.0, "unknown": -1%s}' % (b"0" * 400), b"\xff\xfe\x00\x80 binary",
               b'{"t_s": NaN}', b"{" * 100_000, b'{"t_s": "1.0"}', b"[1, 2]"]
    lines = [json.dumps({**samples[0], "t_s": -1e12}).encode()]  # an absurd first stamp
    n_hostile = 0
    for k, g in enumerate(good):
        lines.append(g)
        if k % 20 == 10:
            lines.append(hostile[(k // 20) % len(hostile)])
            n_hostile += 1
        if k == 200:
            lines.append(json.dumps({**samples[k], "t_s": 1e12}).encode())  # one wild stamp
    proc = subprocess.run(CMD + ["--model", str(model_dir), "--source", "-", "--sink", "stdout"],
                          input=b"\n".join(lines) + b"\n", capture_output=True, timeout=180)
    err = proc.stderr.decode()
    assert proc.returncode == 0, err
    assert "Traceback" not in err
    out = [json.loads(x, parse_constant=lambda tok: pytest.fail(f"non-finite {tok}"))
           for x in proc.stdout.splitlines()]
    # every tick served: the absurd first one, the good ones and the wild one
    assert len(out) == 1 + len(samples) + 1
    assert [m["seq"] for m in out] == list(range(len(out)))
    reasons = [m["fallback_reason"] for m in out]
    assert reasons[1:5] == ["clock_jump"] * 4 and reasons.count("clock_jump") == 5
    assert all(math.isfinite(v) for m in out for v in m["slip_desired"] + m["slip_measured"])
    assert "malformed sample skipped (too_deep" in err and "clock jump" in err and "re-anchored" in err
    assert f"malformed input: {n_hostile} (" in err and "5 clock-jump ticks, 1 re-anchors" in err
    assert all(f"{reason} " in err for reason in ("too_deep", "number_out_of_range", "not_utf8",
                                                  "non_finite", "too_large", "bad_t_s", "not_an_object"))
    cruise = [m for m in out if 6.5 <= m["t_s"] <= 7.5]  # healthy and classified again
    assert cruise and all(m["estimator_ok"] and not m["fallback"] and m["terrain_class"] == 2
                          for m in cruise)


@pytest.mark.acceptance
def test_predict_says_what_a_damaged_log_lost(tmp_path, model_dir, capsys):
    """The damage counts of a log's ingest reach predict, before serving and in the summary."""
    from terrainml.io.ingest import load_run
    from terrainml.io.mcap_writer import RosMcapWriter
    from terrainml.stream.app.options import ServeOptions
    from terrainml.stream.app.runner import run_predict

    good, bad = tmp_path / "good.mcap", tmp_path / "bad.mcap"
    with RosMcapWriter(good, 3, chunk_size=8 * 1024) as w:   # small chunks: one can be lost
        for k in range(600):
            t = k / 100
            w.write_imu(t, (0.0, 0.0, 9.81), (0.0, 0.0, 0.0))
            w.write_wheel_joints(t, [1.0 / 0.165] * 3, [0.0] * 3)
            w.write_motor_current(t, [1.0] * 3)
    corrupt_middle_chunk(good, bad)
    lost = sum(d["corrupt"] for d in load_run(bad).report.topics.values())
    assert lost > 0
    assert run_predict(ServeOptions(model=model_dir, source=str(bad), sinks=("stdout",))) == 0
    err = capsys.readouterr().err
    assert err.count("damaged:") == 2 and f"{lost} corrupt message" in err
    assert run_predict(ServeOptions(model=model_dir, source=str(good), sinks=("stdout",))) == 0
    assert "damaged:" not in capsys.readouterr().err
