"""CLI of the stream area: ``terrainml predict`` (reference: docs/predict.md)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, List, Optional

import typer

from terrainml.commands._help import BUILTIN_MAPS, BUILTIN_ROBOTS, listed
from terrainml.commands._common import fail, open_dataset_spec, open_robot

#: predict's help: a summary, one example, and where the reference is (docs/predict.md)
_PREDICT_HELP = (
    "Serve per-wheel desired slip: one message per base-rate tick, from a log, ROS 2, UDP or "
    "stdin to every sink. Logs and the summary go to stderr.\n\n"
    "Example (a live ROS 2 robot):\n\n"
    "terrainml predict --model runs/husky --robot husky --source ros2://0 --topics husky_ros2 --sink ros2://0\n\n"
    "Every source, sink and option, with examples and exit codes: docs/predict.md.")


def _record_format(record_format: Optional[str], record_unknown: Optional[Path]) -> str:
    """The recorder's format from ``--record-format`` (exit 2 without ``--record-unknown`` or
    for a format the recorder does not write)."""
    from terrainml.stream.app.recorder import RECORD_FORMATS

    if record_format is not None and record_unknown is None:
        fail(f"--record-format {record_format}: needs --record-unknown DIR (the folder to record into)")
    fmt_rec = (record_format or RECORD_FORMATS[0]).strip().lower()
    if fmt_rec not in RECORD_FORMATS:
        fail(f"--record-format {record_format!r}: expected one of {', '.join(RECORD_FORMATS)}")
    return fmt_rec


def _serve_options(*, model: Path, source: str, sinks: List[str], robot: Optional[str], preset: Optional[str],
                   realtime: bool, idle_timeout_s: Optional[float], verbose: bool, max_clock_gap_s: Optional[float],
                   reanchor_after: Optional[int], trusted_key: Optional[List[Path]], topics: Optional[str],
                   dataset: Any, record_unknown: Optional[Path], record_format: Optional[str], closed_set: bool,
                   settle_m: Optional[float]) -> Any:
    """``predict``'s flags resolved, once, into the :class:`~terrainml.stream.app.options.ServeOptions`
    the stream takes (exit 2 on a flag that cannot be resolved). A flag not given keeps the
    default of the setting it sets (:class:`~terrainml.stream.tick.config.ServingConfig`,
    :class:`~terrainml.stream.tick.fusion.FusionConfig`)."""
    from terrainml.stream.app.options import CLASSIFY_LAG_TICKS, ServeOptions
    from terrainml.stream.tick.config import ServingConfig
    from terrainml.stream.tick.fusion import FusionConfig
    from terrainml.stream.transports.sources import SourceOptions

    clock = {k: v for k, v in (("max_clock_gap_s", max_clock_gap_s), ("reanchor_after", reanchor_after))
             if v is not None}
    fusion = FusionConfig() if settle_m is None else FusionConfig(settle_m=settle_m)
    config = ServingConfig(preset=preset, classify_lag_ticks=CLASSIFY_LAG_TICKS, open_set=not closed_set,
                           fusion=fusion, **clock)
    reading = SourceOptions(realtime=realtime, idle_timeout_s=idle_timeout_s, topic_map=topics, dataset=dataset,
                            max_clock_gap_s=config.max_clock_gap_s, reanchor_after=config.reanchor_after)
    return ServeOptions(model=model, source=source, sinks=tuple(sinks), robot=open_robot(robot) if robot else None,
                        config=config, source_options=reading, trusted_keys=tuple(trusted_key or ()),
                        record_unknown=record_unknown, record_format=_record_format(record_format, record_unknown),
                        verbose=verbose)


def register(app: typer.Typer) -> None:
    """Add this area's commands to the top-level app."""

    @app.command(help=_PREDICT_HELP)
    def predict(
        model: Path = typer.Option(..., "--model", metavar="DIR", help="Model folder."),
        source: str = typer.Option(..., "--source", metavar="SPEC",
                                   help="Log file, ros2://N, udp://HOST:PORT or - (stdin)."),
        sink: List[str] = typer.Option(["stdout"], "--sink", metavar="SPEC", show_default=False,
                                       help="stdout (default), ros2://N, udp://, can://, mcap:FILE, "
                                            "foxglove://; repeatable."),
        realtime: bool = typer.Option(False, "--realtime", help="Pace a log at its stamps."),
        robot: Optional[str] = typer.Option(None, "--robot", metavar="NAME",
                                             help=f"{listed(BUILTIN_ROBOTS)} or YAML (the model's)."),
        preset: Optional[str] = typer.Option(None, "--preset", metavar="NAME", help="EKF preset (the model's)."),
        idle_timeout_s: Optional[float] = typer.Option(None, "--idle-timeout-s", metavar="S",
                                                       help="Silent input: exit 3."),
        verbose: bool = typer.Option(False, "--verbose", "-v", help="Log more on stderr."),
        max_clock_gap_s: Optional[float] = typer.Option(None, "--max-clock-gap-s", min=1e-3, metavar="S",
                                                        help="A t_s step past S: jump."),
        reanchor_after: Optional[int] = typer.Option(None, "--reanchor-after", min=1, metavar="K",
                                                     help="Re-anchor after K samples."),
        trusted_key: Optional[List[Path]] = typer.Option(None, "--trusted-key", metavar="KEY",
                                                         help="Serve only a model signed for KEY.pub."),
        topics: Optional[str] = typer.Option(None, "--topics", metavar="MAP", help=f"{listed(BUILTIN_MAPS)} or YAML."),
        fmt: Optional[str] = typer.Option(None, "--format", "--spec", metavar="SPEC",
                                          help="Dataset spec of the log."),
        allow_outside: bool = typer.Option(False, "--allow-outside-spec-dir", help="Spec may read outside."),
        record_unknown: Optional[Path] = typer.Option(None, "--record-unknown", metavar="DIR",
                                                      help="Record unknown ground."),
        record_format: Optional[str] = typer.Option(None, "--record-format", metavar="FMT",
                                                    help="parquet (default), mcap."),
        closed_set: bool = typer.Option(False, "--closed-set", help="No unknown_terrain."),
        settle_m: Optional[float] = typer.Option(None, "--settle-m", min=0.0, metavar="M",
                                                 help="Metres a flagged change must last before unknown."),
    ) -> None:
        from terrainml.stream.app.runner import run_predict

        code = run_predict(_serve_options(
            model=model, source=source, sinks=sink, robot=robot, preset=preset, realtime=realtime,
            idle_timeout_s=idle_timeout_s, verbose=verbose, max_clock_gap_s=max_clock_gap_s,
            reanchor_after=reanchor_after, trusted_key=trusted_key, topics=topics,
            dataset=open_dataset_spec(fmt, allow_outside), record_unknown=record_unknown,
            record_format=record_format, closed_set=closed_set, settle_m=settle_m))
        if code:
            raise typer.Exit(code)
