"""CLI of the simulator area: ``terrainml sim generate`` and ``terrainml sim plot``.

Bad input gives a clear message and exit code 2, never a traceback. The simulator (numba kernels)
and matplotlib are imported inside the commands so that ``terrainml --help`` stays fast.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

from terrainml.classes import N_CLASSES, TERRAIN_CLASSES, class_id, class_name
from terrainml.commands._common import check_n_jobs, check_output_writable, console, fail, open_robot
from terrainml.commands._help import listed, robot_help

sim_app = typer.Typer(name="sim", help="Simulate the reference robot on the eight terrain classes "
                      "(labelled ROS 2 MCAP logs with ground truth).", no_args_is_help=True)


@sim_app.command("generate")
def generate(
    out: Path = typer.Option(..., "--out", "-o", help="RUN.mcap (or .parquet) for one run; a folder "
                             "with --runs-per-class."),
    terrain: Optional[str] = typer.Option(None, "--terrain", help="Terrain class (one run): "
                                           f"{listed(TERRAIN_CLASSES)}, or its id."),
    scenario: str = typer.Option("straight", "--scenario", help="straight, omni, arc, reversal, "
                                 "stop_and_go, mixed, patch_map, course_stop_and_go (one run)."),
    speed_mps: float = typer.Option(1.0, "--speed-mps", help="Cruise speed (m/s)."),
    duration_s: Optional[float] = typer.Option(None, "--duration-s", help="Run length (s). One run: "
                                               "default 30; dataset: default 60-120 drawn per run."),
    seed: int = typer.Option(0, "--seed", help="Seed; per-run seeds are SeedSequence(seed).spawn(n)."),
    runs_per_class: Optional[int] = typer.Option(None, "--runs-per-class", help="Write a labelled "
                                                 "dataset: this many runs of every class."),
    n_jobs: int = typer.Option(1, "--n-jobs", help="Parallel jobs for a dataset (joblib; -1: all cores)."),
    fmt: str = typer.Option("mcap", "--format", help="Dataset file format: mcap or parquet."),
    brake: bool = typer.Option(True, "--brake/--no-brake", help="Straight scenario: stop at the end."),
    robot: Optional[str] = typer.Option(None, "--robot", help=robot_help()),
) -> None:
    """Simulate one labelled run, or a labelled dataset with an index.

    Example (one run): terrainml sim generate --terrain short_grass --scenario straight --speed-mps 1.0
    --duration-s 30 --seed 1 --out runs/grass.mcap

    Example (dataset): terrainml sim generate --runs-per-class 4 --seed 0 --out runs/simdata --n-jobs 2
    """
    from terrainml.sim.scenarios import SCENARIOS

    spec = open_robot(robot)
    check_n_jobs(n_jobs)
    if duration_s is not None and not (1.0 <= duration_s <= 3600.0):
        fail(f"--duration-s must be in [1, 3600] s, got {duration_s}")
    if not (0.05 <= abs(speed_mps) <= 3.0):
        fail(f"--speed-mps must be 0.05..3 m/s in magnitude, got {speed_mps}")
    if runs_per_class is not None:
        if runs_per_class < 1:
            fail(f"--runs-per-class must be >= 1, got {runs_per_class}")
        if fmt not in ("mcap", "parquet"):
            fail(f"--format must be mcap or parquet, got {fmt!r}")
        check_output_writable(out, folder=True)  # a dataset needs an output folder
        from terrainml.sim.generate import generate_dataset

        with Progress(TextColumn("[bold]sim[/] runs"), BarColumn(), MofNCompleteColumn(),
                      TimeRemainingColumn(), console=console) as progress:
            task = progress.add_task("runs", total=runs_per_class * N_CLASSES)
            index = generate_dataset(out, runs_per_class, seed, n_jobs=n_jobs, duration_s=duration_s,
                                     fmt=fmt, robot=spec,
                                     progress=lambda d, t: progress.update(task, completed=d, total=t))
        console.print(f"[green]wrote[/] {runs_per_class * N_CLASSES} runs ({runs_per_class} on each of "
                      f"{listed(TERRAIN_CLASSES)}) and {index}", highlight=False)
        return
    if scenario not in SCENARIOS:
        fail(f"--scenario: unknown scenario {scenario!r}; expected one of: {', '.join(SCENARIOS)}")
    mixed = scenario in ("mixed", "patch_map", "course_stop_and_go")   # the scenario lays out the terrains
    if not mixed:
        if terrain is None:
            fail("--terrain is required for one run (or give --runs-per-class for a dataset)")
        try:
            terrain_id = class_id(terrain)
        except ValueError as exc:
            fail(f"--terrain: {exc}")
    else:
        terrain_id = 0
    if out.suffix not in (".mcap", ".parquet"):
        fail(f"{out}: output must end in .mcap or .parquet")
    check_output_writable(out)
    from terrainml.sim.generate import simulate, write_run

    kw = {"brake": brake} if scenario == "straight" else {}
    with Progress(TextColumn("[bold]sim[/] {task.description}"), BarColumn(), TimeRemainingColumn(),
                  console=console, transient=True) as progress:
        task = progress.add_task(out.name, total=2)
        res = simulate(terrain_id, scenario, speed_mps=speed_mps, duration_s=duration_s or 30.0, seed=seed,
                       robot=spec, **kw)
        progress.update(task, completed=1)
        write_run(res, out)
        progress.update(task, completed=2)
    where = "on the scenario's terrain layout" if mixed else f"on {class_name(terrain_id)}"
    console.print(f"[green]wrote[/] {out}  ({scenario} {where}: distance {res.distance_m:.1f} m, energy "
                  f"{res.energy_j:.0f} J, stuck events {res.stuck_events})", highlight=False)


@sim_app.command("plot")
def plot(
    run: Path = typer.Argument(..., help="Simulated run (.mcap or .parquet with truth)."),
    out: Path = typer.Option(..., "--out", "-o", help="Output folder for the PNGs."),
    robot: Optional[str] = typer.Option(None, "--robot", help=robot_help()),
) -> None:
    """Plot true and measured slip per wheel (like thesis Fig. 7.2-7.4).

    Measured = design §7.1 slip from the raw encoder speed and a camera-based wheel-centre velocity
    (no EKF).

    Example: terrainml sim plot runs/grass.mcap --out runs/plots
    """
    from terrainml.sim.plot import plot_run

    if not run.is_file():
        fail(f"{run}: file not found")
    check_output_writable(out, folder=True)
    try:
        paths = plot_run(run, out, open_robot(robot))
    except (ValueError, KeyError) as exc:
        fail(str(exc))
    for p in paths:
        console.print(f"[green]wrote[/] {p}")


def register(app: typer.Typer) -> None:
    """Add the ``sim`` sub-app to the top-level app."""
    app.add_typer(sim_app, name="sim")
