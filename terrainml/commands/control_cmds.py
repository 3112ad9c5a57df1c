"""CLI of the control area: ``terrainml control closed-loop`` (design §12, §15).

The controller (online predictor, models) and the simulator are imported inside the command so
that ``terrainml --help`` stays fast.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import typer
from rich.progress import Progress

from terrainml.atomic import write_text
from terrainml.classes import class_id
from terrainml.commands._common import check_output_writable, console, fail

control_app = typer.Typer(help="Traction control in the simulator.", no_args_is_help=True)


@control_app.command("closed-loop", help=(
    "Simulate a straight run on one terrain with a traction-control policy and report energy "
    "per metre, mean speed, mean tractive efficiency and stuck events (JSON).\n\n"
    "Policies: none (no traction control), fixed (slip cap 0.1), terrain-aware (cap at the "
    "served desired slip: the online predictor with --model, else the true class with the "
    "lookup table, reported as an oracle). The control law is the per-wheel slip limiter "
    "(docs/control.md), which acts from rest to cruise; --kp/--ki select the simulator-tuned "
    "slip PID with those gains and --thesis-pid the thesis's P controller instead.\n\n"
    "Example: terrainml control closed-loop --terrain dry_sand --policy terrain-aware "
    "--model runs/svm --duration-s 60 --seed 0 --out sand_aware.json"))
def closed_loop(
    terrain: str = typer.Option(..., "--terrain", help="Terrain class name or id (e.g. dry_sand, 6)."),
    policy: str = typer.Option("terrain-aware", "--policy", help="none, fixed or terrain-aware."),
    model: Optional[Path] = typer.Option(None, "--model", help="Trained model folder (runs/NAME)."),
    duration_s: float = typer.Option(60.0, "--duration-s", help="Simulated duration, s."),
    seed: int = typer.Option(0, "--seed", help="Seed of the terrain draw and sensor noise."),
    speed_mps: float = typer.Option(1.0, "--speed-mps", help="Commanded cruise speed, m/s."),
    kp: Optional[float] = typer.Option(None, "--kp", help="Slip PID proportional gain, rad/s per unit slip "
                                       "(default: tuned)."),
    ki: Optional[float] = typer.Option(None, "--ki", help="Slip PID integral gain, rad/s per (unit slip s) "
                                       "(default: tuned)."),
    thesis_pid: bool = typer.Option(False, "--thesis-pid", help="Thesis P controller (Kp 1, two-sided, "
                                    "no feed-forward)."),
    scenario: str = typer.Option("straight", "--scenario", help="straight (1 m/s^2 start, cruise, brake) or "
                                 "step_stop_and_go (speed steps, hard starts)."),
    out: Optional[Path] = typer.Option(None, "--out", help="Write the JSON report here."),
) -> None:
    from terrainml.control.pid import SlipPIDConfig
    from terrainml.control.traction import POLICIES, tuned_config
    from terrainml.experiments.closed_loop import SCENARIOS, ClosedLoopControl, run_closed_loop
    from terrainml.robot import reference_robot

    if policy not in POLICIES:
        fail(f"--policy {policy!r}: expected one of {', '.join(POLICIES)}")
    if scenario not in SCENARIOS:
        fail(f"--scenario {scenario!r}: expected one of {', '.join(SCENARIOS)}")
    try:
        class_id(terrain)
    except ValueError as exc:
        fail(f"--terrain: {exc}")
    if model is not None and not model.is_dir():
        fail(f"--model {model}: no such model folder")
    if out is not None:
        check_output_writable(out)  # before the simulation, not after it
    try:
        over = {k: v for k, v in (("kp", kp), ("ki", ki)) if v is not None}
        # the limiter is the default law; a PID only when its gains or the thesis form are asked
        pid = (SlipPIDConfig(**over) if thesis_pid
               else tuned_config(reference_robot(), **over) if over else None)
    except ValueError as exc:
        fail(str(exc))
    with Progress(console=console, transient=True) as bar:
        task = bar.add_task(f"closed loop {terrain} / {policy}", total=1.0)
        try:
            report = run_closed_loop(terrain, policy, control=ClosedLoopControl(model=model, pid=pid),
                                     duration_s=duration_s, seed=seed,
                                     speed_mps=speed_mps, scenario=scenario,
                                     progress=lambda f: bar.update(task, completed=f))
        except ValueError as exc:  # model refused, bad parameters
            fail(str(exc))
    text = json.dumps(report, indent=2)
    if out is not None:
        write_text(out, text + "\n")
        console.print(f"wrote {out}")
    print(text)


def register(app: typer.Typer) -> None:
    """Add this area's commands to the top-level app."""
    app.add_typer(control_app, name="control")
