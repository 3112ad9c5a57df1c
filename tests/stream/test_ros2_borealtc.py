"""`terrainml predict` serving a real BorealTC run on a Husky's ROS 2 topics, under input faults.

The independent peer (``ros2_peer.py --borealtc``: the csv module and its own cyclonedds IDL
classes, no terrainml code) publishes the BorealTC run ASPHALT_04 (49.5 s, driven mostly straight
after 4 s at rest) as a Husky does, in real time: ``/joint_states`` (the four ``*_wheel_joint``
velocities, 6.5 Hz) and ``/imu/data`` (100 Hz, no orientation), header stamps 1_700_000_000 s + the
csv time, with one fault per run. ``predict --robot husky --topics husky_ros2`` serves it over DDS
(ros2 sink and stdout); a second peer records what it publishes.

Model (module fixture, about 20 s): an SVM (C 10, gamma ``scale``) on ``chunks`` windows of the
wheels and imu groups (what ``husky_ros2`` maps: no currents), trained on the first three runs
with an IMU file of every class, the replayed run left out (``runs_with_imu``). Both were chosen
before any fault run; ``chunks`` over ``short`` because, served offline on the fault-free run,
the ``short`` model named ASPHALT on 47% of the ticks (``short``'s motion rules keep 2% of the
SNOW training windows) against 90% for ``chunks``.

Reference: the class that ``predict --source LOG`` serves at each tick of the same run written
as an MCAP by the peer (``ros2_peer.py write``: the same messages, no fault). A fault-free DDS
replay serves exactly that (measured once: 4954 of 4954 ticks equal in every decision field),
so it stands in for a fault-free real-time run, and each pause test checks it again on the ticks
before its fault. Not the folder label: the first 4 s are at rest, where no class is served
(``none``), with or without a fault.

Acceptance tier (``make test-all``): four real-time runs of about 70 s each.
"""

from __future__ import annotations

import bisect
import csv
import json
import math
import subprocess
import sys
from pathlib import Path

import pytest
from test_ros2_faults import Run
from test_ros2_interop import ENV, PEER, PREDICT

pytestmark = pytest.mark.acceptance  # real-time DDS with peer processes on a real run

BOREAL = Path(__file__).resolve().parents[2].parent / "shared" / "datasets" / "borealtc"
REPLAYED = "ASPHALT_04"
SOURCE = ("--borealtc", f"{BOREAL / 'ASPHALT'}:04")
HUSKY = ("--robot", "husky", "--topics", "husky_ros2")
EPOCH_NS = 1_700_000_000 * 1_000_000_000      # the peer's stamp of csv time 0
END_S = 49.5                                  # the run's last stamp (csv time)
AT_S, FAULT_S = 10.0, 10.0                    # every fault: 10 s from 10 s of csv time


@pytest.fixture(scope="module")
def husky_model(tmp_path_factory):
    if not BOREAL.is_dir():
        pytest.skip(f"real dataset not present at {BOREAL}")
    from terrainml.experiments.borealtc import runs_with_imu
    from terrainml.features.windows import window_spec
    from terrainml.io.ingest import load_dataset
    from terrainml.pipeline.dataset import build_from_tables
    from terrainml.pipeline.train import train
    from terrainml.pipeline.train_options import TrainOptions
    from terrainml.robot import load_robot

    husky = load_robot("husky")
    tables, _ = load_dataset("borealtc", BOREAL)
    runs = runs_with_imu(tables, 3, exclude=[REPLAYED])
    assert len(runs) == 15 and REPLAYED not in {str(t["run_id"].iloc[0]) for t in runs}
    ds = build_from_tables(runs, husky, spec=window_spec("chunks").resolve(husky, ["wheels", "imu"]))
    out = tmp_path_factory.mktemp("husky") / "model"
    train(ds, out, ["svm"], TrainOptions(folds=2, seed=0, ablation=False,
                                         model_params={"svm": {"C_grid": (10.0,), "gamma_grid": ("scale",)}}))
    return out


@pytest.fixture(scope="module")
def reference(husky_model, tmp_path_factory) -> dict[int, str]:
    """Served class at each 10-ms tick (csv time x 100) of ``predict --source`` on the run's MCAP."""
    log = tmp_path_factory.mktemp("husky_log") / "run.mcap"
    subprocess.run([sys.executable, PEER, "write", *SOURCE, "--out", str(log)], check=True, timeout=120, env=ENV,
                   capture_output=True)
    out = subprocess.run(PREDICT + ["--model", str(husky_model), *HUSKY, "--source", str(log), "--sink", "stdout"],
                         capture_output=True, text=True, timeout=600, env=ENV)
    assert out.returncode == 0, out.stderr
    ref = {round(m["t_s"] * 100): m["terrain_name"] for m in map(json.loads, out.stdout.splitlines())}
    assert len(ref) > 4900 and sum(c == "ASPHALT" for c in ref.values()) > 0.8 * len(ref)
    return ref


def _run(model, tmp, *peer_args, idle_s=4.0) -> Run:
    return Run(model, SOURCE, tmp, *peer_args, idle_s=idle_s, predict_args=HUSKY, listen_idle_s=4.0)


def _t(row: dict) -> float:
    """A received message's csv time (s)."""
    return (row["stamp_ns"] - EPOCH_NS) * 1e-9


def _share(r: Run, ref: dict[int, str], t0: float, t1: float) -> tuple[float, int]:
    """Share of the Classification messages stamped in [t0, t1) that name the reference's class."""
    msgs = [x for x in r.rx if x["topic"] == "/terrainml/terrain" and t0 <= _t(x) < t1]
    good = sum(x["results"][0][0] == ref.get(round(_t(x) * 100)) for x in msgs)
    return good / max(len(msgs), 1), len(msgs)


@pytest.mark.parametrize("topic, gap", [("/imu/data", "10.0"), ("/joint_states", "10.2")])
def test_one_topic_paused_for_10_s_serves_the_class_again(husky_model, reference, tmp_path, topic, gap):
    """The class is back on >= 80% of Classification messages from 3 s after the return to the end.
    /joint_states publishes at 6.5 Hz: its last message before the pause is 0.15 s before it, so
    its silence is 10.2 s (stamps 9.846 -> 20.000 s)."""
    r = _run(husky_model, tmp_path, "--pause-topic", topic, "--pause-at-s", str(AT_S), "--pause-s", str(FAULT_S))
    before, n_before = _share(r, reference, 2.0, AT_S)
    after, n_after = _share(r, reference, AT_S + FAULT_S + 3.0, END_S + 1.0)
    print(f"{topic}: served class as the reference {before:.1%} of {n_before} before the pause, "
          f"{after:.1%} of {n_after} from 3 s after the return")
    assert n_before > 700 and before >= 0.95, (before, n_before)     # the fault-free part: the reference
    assert n_after > 2400 and after >= 0.8, (after, n_after)
    assert f"topic {topic} publishes again after {gap} s" in r.err
    inside = [d for d in r.diag if AT_S + 1.0 <= _t(d) < AT_S + FAULT_S]
    assert inside and all(d["level"] == 2 and d["message"] == "estimator unhealthy" for d in inside)
    warn = [[s for s in d["all"] if s["name"] == f"terrainml: input {topic}"] for d in inside]
    assert all(s and s[0]["level"] == 1 and f"{topic} silent for" in s[0]["message"] for s in warn)


def test_every_topic_paused_for_10_s_diagnostics_go_on_at_warn_or_above(husky_model, reference, tmp_path):
    """No tick exists while every topic is silent: /diagnostics goes on at 1 Hz of wall time, level
    >= 1 (ERROR, "no input for N s"), and serving resumes on a new timeline."""
    r = _run(husky_model, tmp_path, "--pause-topic", "all", "--pause-at-s", str(AT_S), "--pause-s", str(FAULT_S),
             idle_s=15.0)
    terrain = [x for x in r.rx if x["topic"] == "/terrainml/terrain"]
    # the silence as the listener saw it: no Classification for 10 s of wall time after the tick at 10 s
    gaps = [(x["wall_s"], y["wall_s"]) for x, y in zip(terrain, terrain[1:])
            if y["wall_s"] - x["wall_s"] > 5.0 and _t(x) < AT_S + 0.1]
    assert len(gaps) == 1, gaps
    a, b = gaps[0]
    silent = [d for d in r.diag if a < d["wall_s"] < b]
    spacing = [y["wall_s"] - x["wall_s"] for x, y in zip(silent, silent[1:])]
    print(f"every topic: {len(silent)} /diagnostics in {b - a:.1f} s without data, levels "
          f"{sorted({d['level'] for d in silent})}, at most {max(spacing):.2f} s apart; served class as the "
          f"reference {_share(r, reference, AT_S + FAULT_S + 3.0, END_S + 1.0)[0]:.1%} from 3 s after the return")
    assert len(silent) >= 8 and max(spacing) <= 1.5
    assert all(d["level"] >= 1 for d in silent), [(round(d["wall_s"] - a, 2), d["message"], d["values"])
                                                  for d in silent if d["level"] < 1]
    assert sum(d["message"].startswith("no input for") for d in silent) >= len(silent) - 1
    assert "every topic publishes again after 10.0 s of silence" in r.err
    assert r.served[-1]["t_s"] > END_S - 0.5              # serving goes on to the end


def test_nan_left_wheel_speeds_keep_odometry_and_say_invalid_values(husky_model, tmp_path):
    """NaN velocity on both left joints for 10 s: /terrainml/odometry keeps at least half its rate
    and is never NaN (the right wheels and the IMU's yaw rate give it); the log says the wheels
    group has invalid values, never that it is silent; the topic's status counts them."""
    r = _run(husky_model, tmp_path, "--nan-joint", "front_left_wheel_joint,rear_left_wheel_joint",
             "--nan-at-s", str(AT_S), "--nan-s", str(FAULT_S))
    odo = [x for x in r.rx if x["topic"] == "/terrainml/odometry"]
    rate_before = sum(2.0 <= _t(x) < AT_S for x in odo) / (AT_S - 2.0)
    inside = [x for x in odo if AT_S <= _t(x) < AT_S + FAULT_S]
    speed = _side_speeds()
    err = sorted(abs(x["vx"] - speed(_t(x))) for x in inside)
    print(f"NaN left wheels: odometry {len(inside) / FAULT_S:.1f} Hz through the stretch, {rate_before:.1f} Hz "
          f"before; |vx - mean side speed| median {err[len(err) // 2]:.3f} m/s")
    assert rate_before > 90 and len(inside) >= 0.5 * rate_before * FAULT_S
    assert all(math.isfinite(x[k]) for x in inside for k in ("vx", "vy", "wz"))
    assert err[len(err) // 2] < 0.05                          # the speed, not "unknown"
    assert "sensor group 'wheels' has invalid values" in r.err and "sensor group 'wheels' valid again" in r.err
    assert "sensor group 'wheels' silent" not in r.err
    assert "topic /joint_states silent" not in r.err.split("sensor group 'wheels' valid again")[0]
    notes = {d["values"].get("odometry") for d in r.diag if AT_S + 1.0 <= _t(d) < AT_S + FAULT_S}
    assert notes == {"from 2 of 4 wheels (wheel1, wheel3 invalid)"}, notes
    status = [s for d in r.diag for s in d["all"] if s["name"] == "terrainml: input /joint_states"]
    assert any("invalid values" in s["message"] for s in status)


def _side_speeds():
    """The run's mean side speed (m/s) at a csv time: the held value of its pro file (6.5 Hz)."""
    with open(BOREAL / "ASPHALT" / "pro_04.csv", newline="") as fh:
        rows = [(float(x["time"]), 0.5 * (float(x["velL"]) + float(x["velR"]))) for x in csv.DictReader(fh)]
    ts = [t for t, _ in rows]
    return lambda t: rows[max(bisect.bisect_right(ts, t + 1e-9) - 1, 0)][1]
