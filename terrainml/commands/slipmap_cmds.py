"""CLI: ``terrainml slipmap fit|merge|experiment`` (design §13, the IRLS paper).

The robot specs, slip maps (statsmodels), run tables (pyarrow) and the experiment are imported
inside the commands so that ``terrainml --help`` stays fast.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import List, Optional

import typer
from rich.progress import Progress
from rich.table import Table

from terrainml.commands._common import check_output_writable, console, fail, open_robot, open_run
from terrainml.commands._help import robot_help

slipmap_app = typer.Typer(help="Slip maps (IRLS paper): per-terrain robust slippage estimators, "
                               "merged across robots.\n\nExample: terrainml slipmap experiment --robots 5 "
                               "--laps 5 --seed 0 --out runs/slipmap/report.json",
                          no_args_is_help=True)


def _load_tables(directory: Path):
    files = sorted(p for p in directory.iterdir() if p.suffix.lower() in (".parquet", ".mcap", ".bag", ".csv"))
    if not files:
        fail(f"{directory}: no run tables (.parquet) or logs (.mcap, .bag, .csv) found")
    for f in files:
        yield f, open_run(f)


@slipmap_app.command("fit")
def fit_cmd(directory: Path = typer.Argument(..., help="Folder of run tables (.parquet) or logs."),
            out: Path = typer.Option(..., "--out", help="Output slip map (JSON message)."),
            robot: Optional[str] = typer.Option(None, help=robot_help(
                "the spec stored in the tables' metadata, else husky")),
            by: str = typer.Option("terrain", help="'terrain' (one estimator per class) or 'all'."),
            norm: str = typer.Option("huber", help="Robust norm: huber or bisquare."),
            robot_id: str = typer.Option("robot", help="Name of this robot in the message.")) -> None:
    """Fit per-terrain IRLS slippage estimators from a skid-steer robot's runs.

    Reference velocity: gt_vx_mps/gt_vy_mps/gt_yaw_rate_radps if present, else the camera velocity.

    Example: terrainml slipmap fit runs/husky_tables --out runs/maps/husky1.json --robot husky
    """
    from terrainml.robot import RobotSpec, RobotSpecError, builtin_robot
    from terrainml.slipmap.fit import SlipFitError, fit_slip_map
    from terrainml.slipmap.kinematics import side_geometry
    from terrainml.slipmap.slipmap import SlipMapConfig

    if not directory.is_dir():
        fail(f"{directory}: not a folder")
    if by not in ("terrain", "all"):
        fail(f"--by must be terrain or all, got {by!r}")
    if norm not in ("huber", "bisquare"):
        fail(f"--norm must be huber or bisquare, got {norm!r}")
    check_output_writable(out)
    tables = list(_load_tables(directory))
    try:
        if robot is not None:
            spec = open_robot(robot)
        else:
            meta_json = tables[0][1].attrs.get("terrainml", {}).get("robot_spec")
            spec = RobotSpec.from_json(meta_json) if meta_json else builtin_robot("husky")
        _, _, track = side_geometry(spec)
        cfg = SlipMapConfig(norm=norm, input_scale_radps=1.0 / spec.wheel_radius_m,
                            wheel_radius_m=spec.wheel_radius_m, track_width_m=track)
        smap, info = fit_slip_map(((str(f), t) for f, t in tables), spec, by=by, config=cfg, robot_id=robot_id)
    except (RobotSpecError, SlipFitError, ValueError) as exc:
        fail(str(exc))
    if not smap.patches:
        fail(f"{directory}: too few usable samples for any entry ({info['samples_per_entry']})")
    smap.save(out)
    console.print(f"wrote {out}: entries {', '.join(info['fitted_entries'])}; samples "
                  f"{info['samples_per_entry']}")


@slipmap_app.command("merge")
def merge_cmd(maps: List[Path] = typer.Argument(..., help="Slip map messages (JSON) of several robots."),
              out: Path = typer.Option(..., "--out", help="Output global slip map (JSON).")) -> None:
    """Merge robots' local estimates exactly: (sum A_k) theta = sum b_k per entry.

    Example: terrainml slipmap merge robot1.json robot2.json --out global.json
    """
    from terrainml.slipmap.slipmap import SlipMap, SlipMapError, merge_maps

    check_output_writable(out)
    try:
        merged = merge_maps([SlipMap.load(p) for p in maps], robot_id="merged")
    except SlipMapError as exc:
        fail(str(exc))
    merged.save(out)
    console.print(f"wrote {out}: {len(maps)} maps, entries {', '.join(sorted(merged.patches))}")


@slipmap_app.command("experiment")
def experiment_cmd(robots: int = typer.Option(5, help="Robots on the path (paper: 5)."),
                   laps: int = typer.Option(5, help="Laps per robot."),
                   seed: int = typer.Option(0, help="Seed of the terrain map, starts and noise."),
                   norm: str = typer.Option("huber", help="IRLS norm: huber or bisquare."),
                   out: Path = typer.Option(Path("runs/slipmap/report.json"), "--out",
                                            help="Report JSON; the figure is written next to it (.png).")) -> None:
    """Lap experiment of the IRLS paper (Fig. 3-4): none vs exponential vs IRLS compensation.

    Example: terrainml slipmap experiment --robots 5 --laps 5 --seed 0 --out runs/slipmap/report.json
    """
    from terrainml.experiments.slipmap_laps import ExperimentConfig, run_experiment, write_report

    if robots < 1 or laps < 2:
        fail("--robots must be >= 1 and --laps >= 2")
    if norm not in ("huber", "bisquare"):
        fail(f"--norm must be huber or bisquare, got {norm!r}")
    check_output_writable(out)
    check_output_writable(out.with_suffix(".png"))
    cfg = ExperimentConfig(n_robots=robots, n_laps=laps, seed=seed, norm=norm)
    with Progress(console=console, transient=True) as bar:
        task = bar.add_task("simulating", total=1.0)
        result = run_experiment(cfg, progress=lambda m, f: bar.update(task, completed=f,
                                                                      description=f"method {m}"))
    path_json, png = write_report(result, out)
    errs = result.report["mean_tracking_error_m"]
    table = Table(title="mean tracking error per lap (m)")
    table.add_column("method")
    for i in range(laps):
        table.add_column(f"lap {i + 1}", justify="right")
    for m, e in errs.items():
        table.add_row(m, *[f"{v:.4f}" for v in e])
    console.print(table)
    console.print(f"wrote {path_json} and {png}")
    print(json.dumps(errs))


def register(app: typer.Typer) -> None:
    """Add this area's commands to the top-level app."""
    app.add_typer(slipmap_app, name="slipmap")
