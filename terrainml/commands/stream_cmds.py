"""CLI of the stream area: ``terrainml predict`` (design §11, §15)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, List, Optional

import typer

from terrainml.commands._common import ALLOW_OUTSIDE_HELP, fail, open_dataset_spec, open_robot

_EXAMPLE = """
Examples:

  terrainml predict --model runs/svm --source ros2://0 --topics husky_ros2 --sink ros2://0

  terrainml predict --model runs/svm --source runs/demo/course.mcap --sink stdout

  terrainml predict --model runs/svm --source udp://127.0.0.1:9870 --sink udp://127.0.0.1:9871

  terrainml predict --model runs/svm --source - --sink can://virtual/vcan0 --sink mcap:served.mcap

  terrainml predict --model runs/svm --source runs/demo/course.mcap --realtime --sink foxglove://127.0.0.1:8765

  terrainml predict --model runs/svm --trusted-key keys/release.pub --source - --sink stdout

  terrainml predict --model runs/husky --source test1.bag --robot husky --topics husky_robot_localization

  terrainml predict --model runs/boreal --source borealtc/ICE/pro_03.csv --format borealtc

  terrainml predict --model runs/svm --source field.mcap --record-unknown runs/unknown_ground

  terrainml predict --model runs/svm --source ros2://0 --record-unknown runs/unknown_ground --record-format mcap

  (live view: in Foxglove, open connection -> Foxglove WebSocket -> ws://127.0.0.1:8765)
"""


# --help texts of `predict`'s longer options
_TRUSTED_KEY_HELP = (
    'Public key (KEY.pub from `terrainml model keygen`); the model must be signed by it (`terrainml model'
    ' sign`), else it is refused. Repeat for several.')
_TOPICS_HELP = (
    'Log or ros2:// source: topic map YAML (or built-in name: default, husky_robot_localization, '
    'husky_ros2) saying which topics feed which columns, as for `terrainml ingest`.')
_FORMAT_HELP = (
    'CSV/Parquet source: dataset spec (built-in name: borealtc, or SPEC.yaml) giving its column names, '
    'units and scales (e.g. m/s wheel speeds -> rad/s) and side-to-wheel mapping; the source is one file '
    'of a run, as for `terrainml ingest --format`.')
_RECORD_UNKNOWN_HELP = (
    "Folder (created): write every stretch served unknown_terrain (ground unlike the model's training "
    'windows) as a run: its canonical rows (unknown_*.parquet, terrain -1; or unknown_*.mcap with '
    '--record-format mcap) and a JSON sidecar (t_s span, distance, model, mean novelty). Label it '
    '(`terrainml dataset label`, docs/stream.md "Unknown ground") and `terrainml dataset build` takes it.'
    ' A failed write is counted in the summary, never stops serving.')
_RECORD_FORMAT_HELP = (
    'With --record-unknown: parquet (default; a run table that `terrainml dataset label` labels as is) or'
    " mcap (a ROS 2 MCAP log of the stretch with the default topic map's messages, stamped with the "
    "samples' ROS time, to open in Foxglove or replay; to label it, `terrainml ingest` it to Parquet "
    'beside its sidecar first).')
_CLOSED_SET_HELP = (
    "Serve without the model's novelty score: every window is served as one of the model's classes, never"
    ' unknown_terrain (the behaviour before unknown-ground detection; for comparison, or a model whose '
    'training runs covered all the ground it will meet).')
_SETTLE_M_HELP = (
    "Unknown ground: metres of travel that novelty flags beginning on known ground must last before "
    "unknown_terrain is served (default 2.5: a change between known terrains stays flagged until every wheel "
    "has crossed and the drive has settled, 0.8-3.7 m on the reference robot's tuning courses). Flags with no "
    "known ground before them need none. 0: enter after the flagged windows alone.")


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
                   realtime: bool, idle_timeout_s: Optional[float], verbose: bool, max_clock_gap_s: float,
                   reanchor_after: int, trusted_key: Optional[List[Path]], topics: Optional[str], dataset: Any,
                   record_unknown: Optional[Path], record_format: Optional[str], closed_set: bool,
                   settle_m: Optional[float]) -> Any:
    """``predict``'s flags resolved, once, into the :class:`~terrainml.stream.app.options.ServeOptions`
    the stream takes (exit 2 on a flag that cannot be resolved)."""
    from terrainml.stream.app.options import CLASSIFY_LAG_TICKS, ServeOptions
    from terrainml.stream.tick.config import ServingConfig
    from terrainml.stream.tick.fusion import FusionConfig
    from terrainml.stream.transports.sources import SourceOptions

    config = ServingConfig(preset=preset, max_clock_gap_s=max_clock_gap_s, reanchor_after=reanchor_after,
                           classify_lag_ticks=CLASSIFY_LAG_TICKS, open_set=not closed_set,
                           fusion=FusionConfig() if settle_m is None else FusionConfig(settle_m=settle_m))
    reading = SourceOptions(realtime=realtime, idle_timeout_s=idle_timeout_s, topic_map=topics, dataset=dataset,
                            max_clock_gap_s=max_clock_gap_s, reanchor_after=reanchor_after)
    return ServeOptions(model=model, source=source, sinks=tuple(sinks), robot=open_robot(robot) if robot else None,
                        config=config, source_options=reading, trusted_keys=tuple(trusted_key or ()),
                        record_unknown=record_unknown, record_format=_record_format(record_format, record_unknown),
                        verbose=verbose)


def register(app: typer.Typer) -> None:
    """Add this area's commands to the top-level app."""

    @app.command(help="Serve per-wheel desired slip, one JSON message per base-rate tick.\n\n"
                      "Samples (canonical column names + t_s) come from a log, UDP datagrams or "
                      "stdin; each tick emits a DesiredSlip (design §11) to every sink. Logs and "
                      "the end-of-stream summary go to stderr.\n" + _EXAMPLE)
    def predict(
        model: Path = typer.Option(..., "--model", help="Trained model folder (runs/NAME)."),
        source: str = typer.Option(..., "--source",
                                   help="RUN.mcap|.bag|.parquet|.csv, a ROS 2 bag folder, ros2://DOMAIN "
                                        "(live ROS 2 topics over DDS, docs/ros2.md), udp://HOST:PORT, "
                                        "or - (stdin JSON lines)."),
        sink: List[str] = typer.Option(["stdout"], "--sink",
                                       help="ros2://DOMAIN (ROS 2 topics), stdout, udp://HOST:PORT, "
                                            "can://IFACE/CHANNEL, "
                                            "mcap:OUT.mcap or foxglove://HOST:PORT (live view "
                                            "in Foxglove); repeat for several."),
        realtime: bool = typer.Option(False, "--realtime", help="Pace a log source at its own time stamps."),
        robot: Optional[str] = typer.Option(None, "--robot",
                                            help="Robot spec (name or YAML); default: the model's."),
        preset: Optional[str] = typer.Option(None, "--preset", help="EKF preset; default: the model's."),
        idle_timeout_s: Optional[float] = typer.Option(
            None, "--idle-timeout-s",
            help="UDP / ROS 2 source: stop after this many seconds without a datagram or message, with a "
                 "line naming the silent topics, and exit code 3."),
        verbose: bool = typer.Option(False, "--verbose", "-v", help="More log output on stderr."),
        max_clock_gap_s: float = typer.Option(
            1.0, "--max-clock-gap-s", min=1e-3,
            help="Clock policy: a t_s step larger than this (either way) is a clock jump."),
        reanchor_after: int = typer.Option(
            5, "--reanchor-after", min=1,
            help="Clock policy: consistent samples on a new timeline before the stream re-anchors."),
        trusted_key: Optional[List[Path]] = typer.Option(
            None, "--trusted-key",
            help=_TRUSTED_KEY_HELP),
        topics: Optional[str] = typer.Option(
            None, "--topics",
            help=_TOPICS_HELP),
        fmt: Optional[str] = typer.Option(
            None, "--format", "--spec",
            help=_FORMAT_HELP),
        allow_outside: bool = typer.Option(False, "--allow-outside-spec-dir", help=ALLOW_OUTSIDE_HELP),
        record_unknown: Optional[Path] = typer.Option(
            None, "--record-unknown",
            help=_RECORD_UNKNOWN_HELP),
        record_format: Optional[str] = typer.Option(
            None, "--record-format",
            help=_RECORD_FORMAT_HELP),
        closed_set: bool = typer.Option(
            False, "--closed-set",
            help=_CLOSED_SET_HELP),
        settle_m: Optional[float] = typer.Option(
            None, "--settle-m", min=0.0,
            help=_SETTLE_M_HELP),
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
