"""CLI commands of the io area: ``terrainml ingest`` and ``terrainml inspect``.

Exit codes: 0 when a usable table resulted (warnings printed), 2 when not (message names the file
and topic); never a traceback.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import typer
from rich.console import Console
from rich.table import Table

from terrainml.commands._common import (ALLOW_OUTSIDE_HELP, check_output_writable, console, fail, failure_message,
                                        open_dataset_spec, open_robot)
from terrainml.commands._help import listed, robot_help, topics_help
from terrainml.io.dataset_spec_names import BUILTIN_SPECS
from terrainml.robots import REFERENCE_ROBOT


def _progress_callback(progress, task):
    def cb(done: int, total: int) -> None:
        progress.update(task, completed=done, total=total)
    return cb


def ingest(
    log: Path = typer.Argument(..., help="Log to ingest: .mcap (ROS 2), .bag (ROS 1), a ROS 2 bag folder, "
                               ".csv or .parquet (with --format: one file of a dataset run)."),
    out: Path = typer.Option(..., "--out", "-o", help="Output run table (.parquet)."),
    topics: Optional[str] = typer.Option(None, "--topics", help=topics_help()),
    rate_hz: float = typer.Option(100.0, "--rate-hz", help="Base rate of the output table (Hz)."),
    robot: Optional[str] = typer.Option(None, "--robot", help=robot_help(
                                        f"the dataset spec's robot with --format, else {REFERENCE_ROBOT}")),
    chunk_s: float = typer.Option(30.0, "--chunk-s", help="Seconds of log resampled and written at a time "
                                  "(one Parquet row group each); bounds memory for long MCAP/bag logs."),
    fmt: Optional[str] = typer.Option(None, "--format", help=f"Dataset spec: a built-in name ({listed(BUILTIN_SPECS)}) "
                                      "or SPEC.yaml; LOG is then one file of a run (e.g. pro_00.csv) and the run's "
                                      "other files are paired by the spec. Default: LOG is the whole log."),
    allow_outside: bool = typer.Option(False, "--allow-outside-spec-dir", help=ALLOW_OUTSIDE_HELP),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Print errors only."),
) -> None:
    """Ingest a log into the canonical run table (Parquet), streaming in time chunks.

    MCAP and bag logs are read twice (a scan, then chunk by chunk), so memory does not grow with
    the log's length; the file equals `load_run(LOG).table` written with `write_run_parquet`.

    Example: terrainml ingest run.mcap --out runs/run.parquet --robot agrimaro

    Example (real Husky bag): terrainml ingest test1.bag --out husky.parquet --robot husky
    --topics husky_robot_localization

    Example (dataset spec): terrainml ingest borealtc/ICE/pro_03.csv --format borealtc --out ice03.parquet
    """
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    from terrainml.io.damage import damage_summary
    from terrainml.io.ingest import ingest_to_parquet

    check_output_writable(out)
    dataset = open_dataset_spec(fmt, allow_outside)
    robot_spec = None if robot is None else open_robot(robot)   # None: the dataset spec's, else agrimaro
    try:
        with Progress(TextColumn("[bold]ingest[/] {task.description}"), BarColumn(), TimeRemainingColumn(),
                      console=console, transient=True, disable=quiet) as progress:
            task = progress.add_task(str(log), total=None)
            rep = ingest_to_parquet(log, out, robot=robot_spec, topic_map=topics, rate_hz=rate_hz, chunk_s=chunk_s,
                                    progress=_progress_callback(progress, task), dataset=dataset)
        for w in rep.warnings:
            if not quiet:
                console.print(f"[yellow]warning:[/] {w}", highlight=False, soft_wrap=True)
        for e in rep.errors:
            console.print(f"[red]error:[/] {e}", highlight=False, soft_wrap=True)
        if not rep.usable:
            console.print(f"[red]{log}: no usable run table; nothing written[/]", highlight=False, soft_wrap=True)
            raise typer.Exit(2)
    except typer.Exit:
        raise
    except Exception as exc:  # noqa: BLE001 - last line of defence: a message, never a traceback
        fail(failure_message(log, exc, out))
    if not quiet:
        console.print(f"[green]wrote[/] {out}: {rep.rows} rows, {rep.span_s:.1f} s at {rep.rate_hz:g} Hz; valid "
                      + ", ".join(f"{g} {f:.0%}" for g, f in rep.valid_fraction.items()),
                      highlight=False, soft_wrap=True)
        damage = damage_summary(rep)
        if damage.any:   # the same counts are in the table's metadata ("damage")
            console.print(f"[yellow]{log}: {damage.text}[/]", highlight=False, soft_wrap=True)


def inspect(
    log: Path = typer.Argument(..., help="Log to inspect: .mcap (ROS 2), .bag (ROS 1) or a ROS 2 bag folder "
                               "(metadata.yaml with .db3 or .mcap files)."),
    as_json: bool = typer.Option(False, "--json", help="Print the summary as JSON on stdout."),
) -> None:
    """Topics, types, counts, rates, time span, gaps (> 2 periods), corrupt/skipped counts of a log.

    Example: terrainml inspect run.mcap --json
    """
    from terrainml.io.inspect import inspect_log
    from terrainml.io.readers import LogReadError

    try:
        info = inspect_log(log)
    except LogReadError as exc:
        fail(str(exc))
    except Exception as exc:  # noqa: BLE001
        fail(failure_message(log, exc))
    if as_json:
        print(json.dumps(info, indent=2))
    else:
        out = Console(width=max(Console().width, 150))
        out.print(f"[bold]{info['file']}[/] ({info['format']}, {info['size_bytes']:,} bytes): "
                  f"{info['messages']:,} messages over {info['span_s']:.2f} s", highlight=False, soft_wrap=True)
        table = Table("topic", "type", "count", "rate Hz", "gaps", "max gap s", "corrupt", "undecoded")
        for topic, d in info["topics"].items():
            table.add_row(topic, d["type"], f"{d['count']:,}",
                          f"{d['rate_hz']:.1f}" if d["rate_hz"] else "-", str(d["gaps"]),
                          f"{d['max_gap_s']:.3f}" if d["max_gap_s"] is not None else "-",
                          str(d["corrupt"]), str(d["undecoded"]))
        out.print(table)
        if info["truncated"]:
            tr = info.get("truncation") or {}
            out.print(f"[yellow]truncated file: {tr.get('unread_bytes', 0):,} byte(s) at the end unread, "
                      f"{tr.get('incomplete_records', 0)} incomplete record(s); every complete message "
                      "before the cut was read[/]", highlight=False, soft_wrap=True)
        if info["corrupt_chunks"]:
            out.print(f"[yellow]{info['corrupt_chunks']} corrupt chunk(s) skipped[/]")
        for w in info["warnings"]:
            out.print(f"[yellow]warning:[/] {w}", highlight=False, soft_wrap=True)
    if info["messages"] == 0:
        raise typer.Exit(2)


def register(app: typer.Typer) -> None:
    """Add ``ingest`` and ``inspect`` to the top-level app."""
    app.command("ingest")(ingest)
    app.command("inspect")(inspect)
