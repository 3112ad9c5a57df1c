"""The demo (``make demo``): the whole chain on the embedded default, the simulator.

Steps, each a small function taking and returning plain objects:

1. a hand-made run table of the reference robot written to a ROS 2 MCAP, inspected and ingested
   back (the data contract, no simulator involved);
2. the simulator writes a small labelled dataset of ROS 2 MCAP logs (every terrain class, mixed
   scenarios);
3. ``dataset build``: ingest -> 12-state EKF -> slip and wheel state -> windows of the default
   spec (``short``: 1 s windows that exist in stop-and-go, design §8);
4. ``train``: SVM under grouped cross-validation by run, report and artifact with manifest, and
   its sensor members (without IMU, without currents, without the camera) as ``train`` makes them;
5. ``predict``: a held-out mixed-terrain course (terrain transitions, a seed never trained on)
   replayed through the online predictor; what it served is printed against the truth.

Everything lands in ``--out`` (default ``runs/demo``): logs, windows, model folder with
``report.md``, and the served segments. The demo is sized to run in a few minutes on 2 cores;
the acceptance-size experiments live in ``benchmarks/``.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TimeElapsedColumn
from rich.table import Table

from terrainml.io.ingest import load_run
from terrainml.io.inspect import inspect_log
from terrainml.io.mcap_writer import write_run_mcap
from terrainml.pipeline.dataset import build_dataset, write_windows
from terrainml.pipeline.members import fixed_fit, member_jobs, train_members
from terrainml.pipeline.sensor_subsets import member_subsets
from terrainml.pipeline.replay import SETTLE_S
from terrainml.pipeline.train_options import TrainOptions
from terrainml.pipeline.train import train
from terrainml.robot import RobotSpec, reference_robot
from terrainml.schema import wheel_col, write_run_parquet
from terrainml.sim.generate import generate_dataset, simulate, write_run
from terrainml.stream.app.scoring import replay_summary
from terrainml.stream.app.tick_losses import losses_sentence, tick_losses


def handmade_run_table(robot: RobotSpec, seed: int = 0, seconds: float = 20.0,
                       rate_hz: float = 100.0) -> pd.DataFrame:
    """A kinematically consistent hand-made run: accelerate to 1 m/s on a gentle arc, cruise, brake.

    Wheel speeds follow the zero-slip wheel model plus a constant 5% traction slip; the camera sees
    the mount velocity (body axes); the terrain label switches from short grass (2) to dry sand (6)
    half-way. Small seeded noise on the sensors.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * rate_hz)) / rate_hz
    ramp = np.clip(t / 1.0, 0, 1) * np.clip((seconds - 2.0 - t) / 1.0 + 1.0, 0, 1)
    vx = 1.0 * ramp
    r = 0.1 * ramp
    vy = np.zeros_like(t)
    ax = np.gradient(vx, t)
    yaw = np.cumsum(r) / rate_hz
    d: dict[str, np.ndarray] = {"t_s": t}
    slip = 0.05
    for i, wh in enumerate(robot.wheels, start=1):
        ux, uy = vx - r * wh.y_m, vy + r * wh.x_m
        steer = np.arctan2(uy, np.maximum(ux, 1e-3)) if wh.steerable else np.zeros_like(t)
        v_long = ux * np.cos(steer) + uy * np.sin(steer)
        d[wheel_col("omega", i)] = v_long / (1 - slip) / robot.wheel_radius_m + rng.normal(0, 0.02, t.size)
        d[wheel_col("steer", i)] = steer
        d[wheel_col("current", i)] = 1.5 * ramp + 3.0 * ax + rng.normal(0, 0.1, t.size)
    d["imu_ax_mps2"] = ax + rng.normal(0, 0.05, t.size)
    d["imu_ay_mps2"] = r * vx + rng.normal(0, 0.05, t.size)
    d["imu_az_mps2"] = 9.81 + rng.normal(0, 0.05, t.size)
    d["imu_yaw_rate_radps"] = r + rng.normal(0, 0.005, t.size)
    if robot.camera is not None:
        d["cam_vx_mps"] = vx - r * robot.camera.y_m + rng.normal(0, 0.01, t.size)
        d["cam_vy_mps"] = vy + r * robot.camera.x_m + rng.normal(0, 0.01, t.size)
        d["cam_yaw_rate_radps"] = r + rng.normal(0, 0.005, t.size)
        d["cam_yaw_rad"] = yaw
        d["cam_confidence"] = np.full(t.size, 3.0)
    d["cmd_vx_mps"], d["cmd_vy_mps"], d["cmd_yaw_rate_radps"] = vx, vy, r
    d["terrain"] = np.where(t < seconds / 2, 2, 6)
    return pd.DataFrame(d)


def step_write_mcap(table: pd.DataFrame, robot: RobotSpec, path: Path) -> Path:
    return write_run_mcap(table, path, robot)


def step_inspect(path: Path) -> dict:
    return inspect_log(path)


def step_ingest(path: Path, robot: RobotSpec):
    return load_run(path, robot=robot)


def print_summary(console: Console, info: dict, result, parquet: Path) -> None:
    table = Table(title=f"{info['file']}: {info['messages']:,} messages, {info['span_s']:.1f} s")
    for c in ("topic", "type", "count", "rate Hz"):
        table.add_column(c)
    for topic, d in info["topics"].items():
        table.add_row(topic, d["type"], str(d["count"]), f"{d['rate_hz']:.1f}" if d["rate_hz"] else "-")
    console.print(table)
    rep = result.report
    console.print(f"ingested: {rep.rows} rows at {rep.rate_hz:g} Hz, valid "
                  + ", ".join(f"{g} {f:.0%}" for g, f in rep.valid_fraction.items())
                  + f"; terrain classes {sorted(set(result.table['terrain']))}; wrote {parquet}", highlight=False)


DEMO_RUNS_PER_CLASS = 5
DEMO_RUN_DURATION_S = 60.0
DEMO_COURSE_DURATION_S = 120.0


def step_contract(out: Path, robot: RobotSpec, seed: int, console: Console) -> None:
    """1. hand-made table -> MCAP -> inspect -> ingest (the data contract)."""
    table = handmade_run_table(robot, seed=seed)
    mcap_path = step_write_mcap(table, robot, out / "handmade.mcap")
    info = step_inspect(mcap_path)
    result = step_ingest(mcap_path, robot)
    parquet = write_run_parquet(result.table, out / "handmade.parquet")
    print_summary(console, info, result, parquet)


def _progress(console: Console):
    return Progress("[progress.description]{task.description}", BarColumn(), MofNCompleteColumn(),
                    TimeElapsedColumn(), console=console, transient=False)


def step_simulate(out: Path, seed: int, console: Console, runs_per_class: int = DEMO_RUNS_PER_CLASS,
                  duration_s: float = DEMO_RUN_DURATION_S, n_jobs: int = 2) -> Path:
    """2. a small labelled dataset from the simulator (ROS 2 MCAP logs plus index.csv)."""
    logs = out / "logs"
    with _progress(console) as bar:
        task = bar.add_task("simulate labelled runs", total=runs_per_class * 8)
        generate_dataset(logs, runs_per_class, seed, n_jobs=n_jobs, duration_s=duration_s,
                         progress=lambda done, total: bar.update(task, completed=done, total=total))
    return logs


def step_build(logs: Path, out: Path, robot: RobotSpec, console: Console, n_jobs: int = 2):
    """3. ingest -> EKF -> slip/state -> windows (default spec), with the rejection counts."""
    with _progress(console) as bar:
        task = bar.add_task("build windows", total=None)
        ds = build_dataset(logs, robot, n_jobs=n_jobs,
                           progress=lambda done, total, name: bar.update(task, completed=done, total=total))
    write_windows(ds, out / "windows.parquet")
    counts = np.bincount(ds.windows.y, minlength=8)
    sp = ds.spec
    console.print(f"windows: {len(ds.windows)} `{sp.name}` {sp.window_s:g} s windows from "
                  f"{len(set(ds.windows.groups))} runs; "
                  "per class " + ", ".join(str(int(c)) for c in counts), highlight=False)
    return ds


def step_train(ds, out: Path, seed: int, console: Console, folds: int = 5, n_jobs: int = 2) -> Path:
    """4. SVM, grouped CV by run, report and artifact, and its sensor members (served while a
    sensor group is missing, e.g. the tracking camera at low confidence)."""
    model_dir = out / "model"
    options = TrainOptions(folds=folds, seed=seed, n_jobs=n_jobs, ablation=False)
    say = lambda msg: console.log(str(msg))  # noqa: E731 - a Step reads as its text
    with console.status("training SVM (grouped cross-validation by run)..."):
        res = train(ds, model_dir, ("svm",), options, progress=say)
    at_once, jobs = member_jobs(n_jobs, len(member_subsets(ds.sensors)))
    with console.status("training its sensor members..."):
        names = train_members(model_dir, ds.sensors, fixed_fit(ds, ("svm",), replace(options, n_jobs=jobs)),
                              progress=say, n_jobs=at_once)
    summary = (res.manifest.get("metrics_summary") or {}).get("svm", {})
    console.print(f"model: {model_dir} (report: {model_dir / 'report.md'})", highlight=False)
    if summary:
        console.print("grouped CV by run: " + ", ".join(
            f"{k.replace('_', ' ')} {summary[k]['mean']:.3f} ± {summary[k]['std']:.3f}"
            for k in ("balanced_accuracy", "macro_f1", "desired_slip_error_mean") if k in summary),
            highlight=False)
    members = {m["name"]: m for m in json.loads((model_dir / "manifest.json").read_text()).get("sensor_members", [])}
    console.print("sensor members (grouped CV balanced accuracy): " + ", ".join(
        f"{n} on {','.join(members[n]['sensors'])} {members[n]['balanced_accuracy']:.3f}" for n in names),
        highlight=False)
    return model_dir


def step_course(out: Path, seed: int, duration_s: float = DEMO_COURSE_DURATION_S) -> Path:
    """5a. a held-out mixed-terrain course (a seed the training set never used)."""
    res = simulate(None, "mixed", speed_mps=0.8, duration_s=duration_s, seed=10_000 + seed)
    return write_run(res, out / "course.mcap", "demo_course")


def step_serve(model_dir: Path, course: Path, console: Console) -> list[dict]:
    """5b. replay the course through the online predictor; print what it served."""
    losses: list[dict] = []
    segments = replay_summary(model_dir, course, console=console,
                              on_ticks=lambda ticks: losses.append(tick_losses(ticks, SETTLE_S)))
    n = sum(s.get("moving_ticks", 0) for s in segments)
    if n:
        ok = sum(s.get("moving_right", 0) for s in segments)
        n_fb = sum(s.get("moving_ticks", 0) for s in segments if s.get("fallback_reason"))
        console.print(f"served class = terrain under the robot on {ok / n:.0%} of all {n} moving ticks "
                      f"(fallback ticks, {n_fb / n:.0%}, counted wrong: they serve the class-free "
                      "safe cap)", highlight=False)
    if losses and losses[0]["moving_ticks"]:
        console.print(losses_sentence(losses[0]), highlight=False)
    return segments


def run_demo(out: Path, seed: int = 0, console: Console | None = None) -> None:
    console = console or Console(stderr=True, soft_wrap=True)
    if not console.is_terminal:  # logs and CI: wide enough for the tables
        console.width = max(console.width, 120)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    robot = reference_robot()
    console.rule("1. data contract: hand-made run table -> ROS 2 MCAP -> ingest")
    step_contract(out, robot, seed, console)
    console.rule("2. simulator: labelled ROS 2 logs on eight terrains")
    logs = step_simulate(out, seed, console)
    console.rule("3. dataset build: ingest -> EKF -> slip and wheel state -> short windows")
    ds = step_build(logs, out, robot, console)
    console.rule("4. train: SVM, grouped CV by run, report and manifest")
    model_dir = step_train(ds, out, seed, console)
    console.rule("5. predict: held-out mixed-terrain course through the online predictor")
    course = step_course(out, seed)
    segments = step_serve(model_dir, course, console)
    served = sum(s["ticks"] for s in segments)
    console.print(f"[green]demo done[/]: {served} ticks served; everything is in {out}/", highlight=False)
