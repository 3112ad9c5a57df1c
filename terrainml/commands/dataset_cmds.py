"""CLI commands of the dataset area: ``terrainml dataset build``, ``show`` and ``label``.

Exit codes: 0 on success, 2 when the input is unusable (message names the file); never a
traceback.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from rich.table import Table

from terrainml.commands._common import (check_n_jobs, check_output_writable, console, fail, failure_message,
                                        open_dataset)
from terrainml.commands._help import DEFAULT_WINDOWS_PHRASE, WINDOWS_HELP, robot_help
from terrainml.features.window_presets import DEFAULT_WINDOWS
from terrainml.robots import REFERENCE_ROBOT

dataset_app = typer.Typer(help=f"Build window datasets from logs ({DEFAULT_WINDOWS_PHRASE}).", no_args_is_help=True)


def rejection_table(ds) -> Table:
    """A rich table of the per-rule rejection counts and per-run status."""
    name = getattr(getattr(ds, "spec", None), "name", "steady")
    unit = "chunks (n_kept: windows)" if getattr(getattr(ds, "spec", None), "chunk_s", None) else "windows"
    t = Table(title=f"window rules of the '{name}' spec (design §8): {unit} rejected", title_justify="left")
    t.add_column("rule")
    t.add_column("windows", justify="right")
    for k, v in ds.counts.items():
        t.add_row(k, str(v))
    return t


def class_table(ds) -> Table:
    """A rich table of what each class kept and which rule rejected the rest (with hints)."""
    t = Table(title="per class: candidates (windows; chunks for --windows chunks), kept windows, rejections",
              title_justify="left")
    rep = ds.class_report
    if rep is None or not len(rep):
        return t
    rules = [c for c in rep.columns if c not in ("class_id", "class", "runs", "candidates", "kept",
                                                 "kept_share", "hint") and rep[c].sum() > 0]
    # the class names are shown whole (a narrow terminal squeezes the count columns instead)
    t.add_column("class", min_width=max(len(str(n)) for n in rep["class"]), no_wrap=True)
    for c in ["runs", "candidates", "kept", "passed", *rules]:
        t.add_column(c, justify="right")
    for r in rep.to_dict(orient="records"):
        t.add_row(str(r["class"]), str(r["runs"]), str(r["candidates"]), str(r["kept"]),
                  f"{r['kept_share']:.0%}", *[str(r[c]) for c in rules])
    return t


def print_class_report(ds) -> None:
    """The per-class table, then one warning with a hint per class that lost most of its data."""
    console.print(class_table(ds))
    rep = ds.class_report
    for r in ([] if rep is None or not len(rep) else rep.to_dict(orient="records")):
        if r.get("hint"):
            console.print(f"[yellow]warning:[/] class {r['class']}: {r['hint']}", highlight=False)


def window_spec_from_options(windows: str, window_s: Optional[float] = None, hop_s: Optional[float] = None,
                             channels: Optional[str] = None):
    """The named window spec with the command line's overrides (ValueError names a bad value)."""
    from terrainml.features.windows import window_spec

    over = {}
    if window_s is not None:
        over["window_s"] = window_s
        over["hop_s"] = hop_s if hop_s is not None else window_s
    elif hop_s is not None:
        over["hop_s"] = hop_s
    if channels:
        over["channels"] = tuple(c.strip() for c in channels.split(",") if c.strip())
    return window_spec(windows, **over)


def parse_sensors(sensors: Optional[str]) -> Optional[list]:
    """``wheels,currents`` -> ["wheels", "currents"]; None stays None (every group)."""
    if sensors is None:
        return None
    return [g.strip() for g in sensors.split(",") if g.strip()]


def build_with_progress(source: Path, *, robot: Optional[str], preset: str, n_jobs: int,
                        dask_address: Optional[str], fmt: str, quiet: bool = False, spec=None,
                        sensors: Optional[list] = None):
    """Build a Dataset from a folder of logs (or BorealTC layout) with a rich progress bar.

    The edge of ``dataset build`` and ``train --data FOLDER``: the robot (default: the format's,
    :func:`terrainml.pipeline.dataset.dataset_robot`) and the window spec (restricted to
    ``sensors``, ``--sensors``: :func:`terrainml.pipeline.dataset.resolve_spec`) are resolved here
    once; everything below takes the two objects.
    """
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    from terrainml.pipeline.dataset import DatasetError, build_dataset, dataset_robot, resolve_spec
    from terrainml.robot import RobotSpecError

    try:
        rb = dataset_robot(robot, fmt)
        spec = resolve_spec(spec, rb, sensors)
    except (DatasetError, RobotSpecError) as exc:
        fail(str(exc))
    say = None if quiet else (lambda line: console.print(line, highlight=False))
    with Progress(TextColumn("[bold]dataset[/] {task.description}"), BarColumn(), MofNCompleteColumn(),
                  TimeRemainingColumn(), console=console, transient=True, disable=quiet) as progress:
        task = progress.add_task(str(source), total=None)

        def cb(done: int, total: int, name: str) -> None:
            progress.update(task, completed=done, total=total, description=name)

        try:
            return build_dataset(source, rb, preset, spec, n_jobs=n_jobs, dask_address=dask_address,
                                 progress=cb, fmt=fmt, say=say)
        except DatasetError as exc:  # no logs, no BorealTC run: the message names the folder
            fail(str(exc))


def build(
    source: Path = typer.Argument(..., help="Folder of logs (*.mcap, *.bag, *.parquet or *.csv), one log, "
                                  "or a BorealTC folder with --format borealtc."),
    out: Path = typer.Option(..., "--out", "-o", help="Output windows file (.parquet)."),
    n_jobs: int = typer.Option(1, "--n-jobs", "-j", help="Parallel jobs over logs (joblib; -1: all cores)."),
    dask_address: Optional[str] = typer.Option(None, "--dask-address",
                                               help="Dask scheduler tcp://HOST:PORT: process the logs on "
                                                    "that cluster (joblib's Dask backend)."),
    preset: str = typer.Option("robust", "--preset", help="Estimation preset: robust or thesis."),
    robot: Optional[str] = typer.Option(None, "--robot", help=robot_help(f"{REFERENCE_ROBOT} (husky for borealtc)")),
    fmt: str = typer.Option("auto", "--format", help="auto (logs) or borealtc (<CLASS>/pro_XX.csv layout)."),
    windows: str = typer.Option(DEFAULT_WINDOWS, "--windows", help=WINDOWS_HELP),
    sensors: Optional[str] = typer.Option(None, "--sensors", help="Sensor groups to use, e.g. wheels,currents "
                                          "(of wheels, currents, imu, cam; default: all the data has). Without cam "
                                          "on a robot with a camera, the EKF's body velocity (vx, vy, r) is left "
                                          "out too: the camera is its reference."),
    window_s: Optional[float] = typer.Option(None, "--window-s", help="Window length (s); default: the spec's."),
    hop_s: Optional[float] = typer.Option(None, "--hop-s", help="Offline hop (s); default = window length."),
    channels: Optional[str] = typer.Option(None, "--channels", help="Comma-separated channels to keep, e.g. "
                                           "current_1,current_2,vx,vy,r (default: all the robot has)."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Print errors only."),
) -> None:
    """Ingest, estimate and cut windows (--windows) for every log; write one windows Parquet.

    Example: terrainml dataset build data/sim --out data/windows.parquet --n-jobs 2

    Example (cluster): terrainml dataset build logs/ --out w.parquet --dask-address tcp://10.0.0.5:8786
    """
    from terrainml.pipeline.dataset import DatasetError, write_windows

    try:
        spec = window_spec_from_options(windows, window_s, hop_s, channels)
    except ValueError as exc:
        fail(str(exc))
    check_n_jobs(n_jobs)
    check_output_writable(out)
    try:
        ds = build_with_progress(source, robot=robot, preset=preset, n_jobs=n_jobs,
                                 dask_address=dask_address, fmt=fmt, quiet=quiet, spec=spec,
                                 sensors=parse_sensors(sensors))
        bad = ds.runs[ds.runs["status"] != "ok"] if len(ds.runs) else ds.runs
        for row in bad.itertuples():
            console.print(f"[yellow]warning:[/] {row.source}: {row.status}: {row.message}", highlight=False)
        if len(ds.windows) == 0:
            if not quiet:
                console.print(rejection_table(ds))
            fail(f"{source}: no labelled windows of the '{spec.name}' spec; nothing written")
        write_windows(ds, out)
    except typer.Exit:
        raise
    except DatasetError as exc:
        fail(str(exc))
    except Exception as exc:  # noqa: BLE001 - a message, never a traceback
        fail(failure_message(source, exc, out))
    if not quiet:
        console.print(rejection_table(ds))
        print_class_report(ds)
        n_damaged = int((ds.runs["status"] == "damaged").sum()) if len(ds.runs) else 0
        console.print(f"[green]wrote[/] {out}: {len(ds.windows)} windows from {len(ds.runs)} logs "
                      f"({n_damaged} damaged), "
                      f"channels {list(ds.windows.channels)}, classes {ds.class_names}; "
                      f"fingerprint {ds.fingerprint[:16]}", highlight=False)


def show(path: Path = typer.Argument(..., help="Windows file written by `dataset build`.")) -> None:
    """Summarise a windows file: classes, runs, channels, rejection counts, fingerprint.

    Example: terrainml dataset show data/windows.parquet
    """
    ds = open_dataset(path)
    w = ds.windows
    t = Table(title=f"{path}: {len(w)} windows, {len(set(w.groups))} runs", title_justify="left")
    t.add_column("class")
    t.add_column("id", justify="right")
    t.add_column("windows", justify="right")
    t.add_column("runs", justify="right")
    for cid, name in zip(ds.class_ids, ds.class_names):
        m = w.y == cid
        t.add_row(name, str(cid), str(int(m.sum())), str(len(set(w.groups[m]))))
    console.print(t)
    console.print(rejection_table(ds))
    console.print(f"channels {list(w.channels)}; robot {ds.robot.name}; preset {ds.preset}; "
                  f"fingerprint {ds.fingerprint}", highlight=False)


def label(
    run: Path = typer.Argument(..., help="Run table (Parquet), e.g. one written by `terrainml predict "
                               "--record-unknown DIR` (DIR/unknown_*.parquet). An MCAP run (--record-format "
                               "mcap) is refused with the `terrainml ingest` command that turns it into one."),
    terrain: str = typer.Option(..., "--terrain", "-t", help="Its class: a name of the run's class list (the "
                                "model's classes) or a new name (added as the next class id), or a class id."),
    out: Optional[Path] = typer.Option(None, "--out", "-o", help="Labelled run to write (default: replace RUN); "
                                       "its JSON sidecar goes beside it."),
) -> None:
    """Give every row of a recorded run one terrain class, so `dataset build` takes it.

    Example: terrainml dataset label runs/unknown/unknown_20261204T101500Z_001.parquet --terrain SNOW
    --out logs/parquet/snow_field_01.parquet

    Example (then build on it): terrainml dataset build logs/parquet --out w.parquet
    """
    from terrainml.pipeline.labels import label_run

    if out is not None:
        check_output_writable(out)
    try:
        res = label_run(run, terrain, out)
    except Exception as exc:  # noqa: BLE001 - a message naming the file, never a traceback
        fail(failure_message(run, exc, out))
    new = " (a new class)" if res.added else ""
    console.print(f"[green]wrote[/] {res.path}: every row terrain {res.name} (class id {res.class_id}){new}; "
                  f"classes {res.classes}" + (f"; sidecar {res.sidecar}" if res.sidecar else ""), highlight=False)


dataset_app.command("build")(build)
dataset_app.command("show")(show)
dataset_app.command("label")(label)


def register(app: typer.Typer) -> None:
    """Add this area's commands to the top-level app."""
    app.add_typer(dataset_app, name="dataset")
