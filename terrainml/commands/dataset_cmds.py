"""CLI commands of the dataset area: ``terrainml dataset build`` and ``terrainml dataset show``.

Exit codes: 0 on success, 2 when the input is unusable (message names the file); never a
traceback.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from rich.console import Console
from rich.table import Table

console = Console(stderr=True, soft_wrap=True)

dataset_app = typer.Typer(help="Build window datasets (steady 2 s windows) from logs.", no_args_is_help=True)


def _fail(msg: str) -> None:
    console.print(f"[red]error:[/] {msg}", highlight=False)
    raise typer.Exit(2)


def rejection_table(ds) -> Table:
    """A rich table of the per-rule rejection counts and per-run status."""
    t = Table(title="steady-window rules (SYSTEM §8): windows rejected", title_justify="left")
    t.add_column("rule")
    t.add_column("windows", justify="right")
    for k, v in ds.counts.items():
        t.add_row(k, str(v))
    return t


def build_with_progress(source: Path, *, robot: Optional[str], preset: str, n_jobs: int,
                        dask_address: Optional[str], fmt: str, quiet: bool = False, spec=None):
    """Build a Dataset from a folder of logs (or BorealTC layout) with a rich progress bar."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    from terrainml.pipeline.dataset import build_dataset, build_from_tables, find_logs
    from terrainml.robot import load_robot

    if fmt == "borealtc":
        from terrainml.io.borealtc import load_borealtc

        rb = load_robot(robot or "husky")
        tables, rep = load_borealtc(source, robot=rb)
        if not quiet:
            console.print(f"BorealTC: {rep.runs} runs, classes {rep.classes}; runs without IMU "
                          f"(wheel channels invalid, their windows rejected): {len(rep.runs_without_imu)}; "
                          f"skipped: {len(rep.skipped)}", highlight=False)
        if not tables:
            _fail(f"{source}: no BorealTC runs read ({rep.skipped})")
        return build_from_tables(tables, rb, preset, spec, n_jobs=n_jobs)
    if fmt != "auto":
        _fail(f"unknown --format {fmt!r}; expected auto or borealtc")
    paths = find_logs(source)
    rb = load_robot(robot)
    with Progress(TextColumn("[bold]dataset[/] {task.description}"), BarColumn(), MofNCompleteColumn(),
                  TimeRemainingColumn(), console=console, transient=True, disable=quiet) as progress:
        task = progress.add_task(str(source), total=len(paths))

        def cb(done: int, total: int, name: str) -> None:
            progress.update(task, completed=done, total=total, description=name)

        return build_dataset(paths, rb, preset, spec, n_jobs=n_jobs, dask_address=dask_address, progress=cb)


def build(
    source: Path = typer.Argument(..., help="Folder of logs (*.mcap, *.bag, *.parquet or *.csv), one log, "
                                  "or a BorealTC folder with --format borealtc."),
    out: Path = typer.Option(..., "--out", "-o", help="Output windows file (.parquet)."),
    n_jobs: int = typer.Option(1, "--n-jobs", "-j", help="Parallel jobs over logs (joblib; -1: all cores)."),
    dask_address: Optional[str] = typer.Option(None, "--dask-address",
                                               help="Dask scheduler tcp://HOST:PORT: process the logs on "
                                                    "that cluster (joblib's Dask backend)."),
    preset: str = typer.Option("robust", "--preset", help="Estimation preset: robust or thesis."),
    robot: Optional[str] = typer.Option(None, "--robot", help="Robot spec YAML or built-in name "
                                        "(agrimaro, husky). Default: agrimaro (husky for borealtc)."),
    fmt: str = typer.Option("auto", "--format", help="auto (logs) or borealtc (<CLASS>/pro_XX.csv layout)."),
    window_s: float = typer.Option(2.0, "--window-s", help="Window length (s)."),
    hop_s: Optional[float] = typer.Option(None, "--hop-s", help="Offline hop (s); default = window length."),
    channels: Optional[str] = typer.Option(None, "--channels", help="Comma-separated channels to keep, e.g. "
                                           "current_1,current_2,vx,vy,r (default: all the robot has)."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Print errors only."),
) -> None:
    """Ingest, estimate and cut steady windows for every log; write one windows Parquet.

    Example: ``terrainml dataset build data/sim --out data/windows.parquet --n-jobs 2``

    Example (cluster): ``terrainml dataset build logs/ --out w.parquet --dask-address tcp://10.0.0.5:8786``
    """
    from terrainml.features.windows import WindowSpec
    from terrainml.pipeline.dataset import DatasetError, write_windows

    try:
        spec = WindowSpec(window_s=window_s, hop_s=hop_s if hop_s is not None else window_s,
                          channels=None if not channels else tuple(c.strip() for c in channels.split(",") if c.strip()))
    except ValueError as exc:
        _fail(str(exc))
    try:
        ds = build_with_progress(source, robot=robot, preset=preset, n_jobs=n_jobs,
                                 dask_address=dask_address, fmt=fmt, quiet=quiet, spec=spec)
        bad = ds.runs[ds.runs["status"] != "ok"] if len(ds.runs) else ds.runs
        for row in bad.itertuples():
            console.print(f"[yellow]warning:[/] {row.source}: {row.status}: {row.message}", highlight=False)
        if len(ds.windows) == 0:
            if not quiet:
                console.print(rejection_table(ds))
            _fail(f"{source}: no steady labelled windows; nothing written")
        write_windows(ds, out)
    except typer.Exit:
        raise
    except DatasetError as exc:
        _fail(str(exc))
    except Exception as exc:  # noqa: BLE001 - a message, never a traceback
        _fail(f"{source}: {type(exc).__name__}: {exc}")
    if not quiet:
        console.print(rejection_table(ds))
        console.print(f"[green]wrote[/] {out}: {len(ds.windows)} windows from {len(ds.runs)} logs, "
                      f"channels {list(ds.windows.channels)}, classes {ds.class_names}; "
                      f"fingerprint {ds.fingerprint[:16]}", highlight=False)


def show(path: Path = typer.Argument(..., help="Windows file written by `dataset build`.")) -> None:
    """Summarise a windows file: classes, runs, channels, rejection counts, fingerprint.

    Example: ``terrainml dataset show data/windows.parquet``
    """
    from terrainml.pipeline.dataset import DatasetError, read_windows

    try:
        ds = read_windows(path)
    except DatasetError as exc:
        _fail(str(exc))
    w = ds.windows
    t = Table(title=f"{path}: {len(w)} windows, {len(set(w.groups))} runs", title_justify="left")
    t.add_column("class")
    t.add_column("windows", justify="right")
    t.add_column("runs", justify="right")
    for cid, name in zip(ds.class_ids, ds.class_names):
        m = w.y == cid
        t.add_row(f"{cid} {name}", str(int(m.sum())), str(len(set(w.groups[m]))))
    console.print(t)
    console.print(rejection_table(ds))
    console.print(f"channels {list(w.channels)}; robot {ds.robot.name}; preset {ds.preset}; "
                  f"fingerprint {ds.fingerprint}", highlight=False)


dataset_app.command("build")(build)
dataset_app.command("show")(show)


def register(app: typer.Typer) -> None:
    """Add this area's commands to the top-level app."""
    app.add_typer(dataset_app, name="dataset")
