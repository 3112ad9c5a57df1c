"""What ``terrainml predict`` was asked to do, resolved once by the CLI.

:class:`ServeOptions` is built by ``terrainml predict`` (:mod:`terrainml.commands.stream_cmds`)
from its flags, once, and handed to :func:`terrainml.stream.app.runner.run_predict`; nothing below
reads a flag again.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from terrainml.robot import RobotSpec
from terrainml.stream.app.recorder import RECORD_FORMATS
from terrainml.stream.tick.config import ServingConfig
from terrainml.stream.transports.sources import SourceOptions

__all__ = ["CLASSIFY_LAG_TICKS", "ServeOptions"]

#: ``terrainml predict`` classifies in a background thread; results apply 10 ticks (0.1 s) later
CLASSIFY_LAG_TICKS = 10


@dataclass(frozen=True)
class ServeOptions:
    """One ``terrainml predict`` run.

    Attributes
    ----------
    model : the trained model folder (``runs/NAME``).
    source : the ``--source`` spec (:func:`terrainml.stream.transports.sources.open_source`).
    sinks : the ``--sink`` specs (:func:`terrainml.stream.transports.sinks.open_sink`).
    robot : the robot served, or None: the model's.
    config : how the predictor serves (default: the model's preset, classification in a
        background thread :data:`CLASSIFY_LAG_TICKS` ticks behind).
    source_options : how the source is read (pacing, idle timeout, topic map, dataset spec).
    trusted_keys : public keys (``KEY.pub``); when any, the model must be signed by one of them.
    record_unknown : a folder, or None; stretches served ``unknown_terrain`` are written there.
    record_format : the format they are written in, one of :data:`~terrainml.stream.app.recorder.RECORD_FORMATS`.
    verbose : INFO-level log lines on stderr.
    """

    model: Path
    source: str
    sinks: tuple[str, ...] = ("stdout",)
    robot: RobotSpec | None = None
    config: ServingConfig = field(default_factory=lambda: ServingConfig(classify_lag_ticks=CLASSIFY_LAG_TICKS))
    source_options: SourceOptions = SourceOptions()
    trusted_keys: tuple[Path, ...] = ()
    record_unknown: Path | None = None
    record_format: str = RECORD_FORMATS[0]
    verbose: bool = False
